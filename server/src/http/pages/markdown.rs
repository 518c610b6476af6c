//! The participants' README as HTML: the small part of Markdown the run's
//! README uses (headings, paragraphs, `-`/`*` lists with continued lines,
//! indented code, pipe tables, `code` and **strong**). Every character of
//! the text is escaped first; no HTML of the text ever passes through.

/// Escapes `&`, `<`, `>`, `"` and `'` for HTML text and attributes.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

/// One line's inline markup: `code` spans, then **strong** outside them.
fn inline(text: &str) -> String {
    let mut out = String::new();
    for (i, part) in text.split('`').enumerate() {
        if i % 2 == 1 {
            out.push_str("<code>");
            out.push_str(&escape(part));
            out.push_str("</code>");
        } else {
            for (j, piece) in escape(part).split("**").enumerate() {
                if j > 0 {
                    out.push_str(if j % 2 == 1 { "<strong>" } else { "</strong>" });
                }
                out.push_str(piece);
            }
            // An unclosed ** stays open in the text; close it.
            if escape(part).matches("**").count() % 2 == 1 {
                out.push_str("</strong>");
            }
        }
    }
    out
}

fn list_item(line: &str) -> Option<&str> {
    let t = line.trim_start();
    t.strip_prefix("- ").or_else(|| t.strip_prefix("* "))
}

/// The cells of a table row `| a | b |`.
fn cells(line: &str) -> Vec<&str> {
    let t = line.trim();
    let t = t.strip_prefix('|').unwrap_or(t);
    let t = t.strip_suffix('|').unwrap_or(t);
    t.split('|').map(str::trim).collect()
}

/// The README (Markdown) as HTML (see the module's documentation for what
/// is understood; anything else is a paragraph of escaped text).
pub fn markdown_html(text: &str) -> String {
    let mut out = String::new();
    let lines: Vec<&str> = text.lines().collect();
    let mut blocks: Vec<&[&str]> = Vec::new();
    let mut start = 0;
    for (i, l) in lines.iter().enumerate() {
        if l.trim().is_empty() {
            if start < i {
                blocks.push(&lines[start..i]);
            }
            start = i + 1;
        }
    }
    if start < lines.len() {
        blocks.push(&lines[start..]);
    }
    for block in blocks {
        let first = block[0];
        let level = first.chars().take_while(|&c| c == '#').count();
        if (1..=6).contains(&level) && first[level..].starts_with(' ') {
            // Headings one level down: the page has its own <h1>.
            let h = (level + 1).min(6);
            out.push_str(&format!("<h{h}>{}</h{h}>\n", inline(first[level..].trim())));
            if block.len() > 1 {
                out.push_str(&format!("<p>{}</p>\n", inline(&block[1..].join(" "))));
            }
        } else if block.iter().all(|l| l.starts_with("    ")) {
            let indent = block
                .iter()
                .map(|l| l.len() - l.trim_start().len())
                .min()
                .unwrap_or(0);
            let code: Vec<&str> = block.iter().map(|l| &l[indent..]).collect();
            out.push_str(&format!("<pre>{}</pre>\n", escape(&code.join("\n"))));
        } else if block.iter().all(|l| l.trim_start().starts_with('|')) {
            out.push_str("<table class=\"prose\">\n");
            for (i, l) in block.iter().enumerate() {
                let c = cells(l);
                if c.iter()
                    .all(|c| !c.is_empty() && c.chars().all(|x| "-: ".contains(x)))
                {
                    continue;
                }
                let tag = if i == 0 { "th" } else { "td" };
                out.push_str("<tr>");
                for cell in c {
                    out.push_str(&format!("<{tag}>{}</{tag}>", inline(cell)));
                }
                out.push_str("</tr>\n");
            }
            out.push_str("</table>\n");
        } else if list_item(first).is_some() {
            let mut items: Vec<String> = Vec::new();
            for l in block {
                match list_item(l) {
                    Some(item) => items.push(item.trim().to_string()),
                    None => {
                        if let Some(last) = items.last_mut() {
                            last.push(' ');
                            last.push_str(l.trim());
                        }
                    }
                }
            }
            out.push_str("<ul>\n");
            for item in items {
                out.push_str(&format!("<li>{}</li>\n", inline(&item)));
            }
            out.push_str("</ul>\n");
        } else {
            let text: Vec<&str> = block.iter().map(|l| l.trim()).collect();
            out.push_str(&format!("<p>{}</p>\n", inline(&text.join(" "))));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markdown_blocks_and_inline_markup() {
        let md = "# Title\n\nSome `x<y` and **bold** text\non two lines.\n\n\
                  - one\n  continued\n* two\n\n      # image x\n      a 1\n\n\
                  | col | meaning |\n|---|---|\n| `a` | b |\n";
        let html = markdown_html(md);
        assert_eq!(
            html,
            "<h2>Title</h2>\n\
             <p>Some <code>x&lt;y</code> and <strong>bold</strong> text on two lines.</p>\n\
             <ul>\n<li>one continued</li>\n<li>two</li>\n</ul>\n\
             <pre># image x\na 1</pre>\n\
             <table class=\"prose\">\n<tr><th>col</th><th>meaning</th></tr>\n\
             <tr><td><code>a</code></td><td>b</td></tr>\n</table>\n"
        );
    }

    #[test]
    fn html_in_the_text_stays_text() {
        let html = markdown_html("<script>alert(1)</script> & `<b>`\n\n- <img src=x>\n");
        assert!(!html.contains("<script") && !html.contains("<img") && !html.contains("<b>"));
        assert!(html.contains("&lt;script&gt;alert(1)&lt;/script&gt; &amp;"));
        assert!(html.contains("<code>&lt;b&gt;</code>"));
        // An unclosed ** is closed, so no tag leaks past the block.
        assert_eq!(markdown_html("a **b"), "<p>a <strong>b</strong></p>\n");
    }
}
