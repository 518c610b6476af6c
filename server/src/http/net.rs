//! The connection layer of `stepsim serve`: hyper's HTTP/1 server under a
//! watchdog per connection, caps on connections, and a guard on every
//! request body ([`super::limits::Limits`]; docs/server.md, "Threat model").
//!
//! axum's own `serve` has no timeouts: a client that sends half a request
//! and waits held its connection (and a task) for ever. Here each
//! connection is closed when
//!
//! - its request headers take longer than `header_timeout` from their
//!   first byte,
//! - it has no request in flight and has read or written nothing for
//!   `idle_timeout` (kept-alive connections between requests too),
//! - a request is in flight and nothing moved for `check_budget +
//!   idle_timeout` (a backstop: every handler is bounded below that);
//!
//! a request body that stalls or arrives too slowly is cut off by
//! the body guard (`guard_body`; the upload answers 408). Connections past
//! `max_connections`, or past `max_connections_per_addr` from one address,
//! are answered 503 and closed at once, before a byte is read.

use super::limits::Limits;
use axum::Router;
use axum::body::Body;
use axum::extract::{ConnectInfo, Request};
use http_body_util::BodyExt;
use std::collections::HashMap;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::{Duration, Instant};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tower::ServiceExt;

/// Set in a request's extensions by [`guard_body`]: true once its body was
/// cut off for stalling or arriving too slowly.
#[derive(Debug, Clone)]
pub(crate) struct BodyCut(pub(crate) Arc<AtomicBool>);

/// The error of a body cut off by [`guard_body`].
#[derive(Debug)]
struct TooSlow;

impl std::fmt::Display for TooSlow {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("the request body arrived too slowly and was cut off")
    }
}

impl std::error::Error for TooSlow {}

/// A request body under `limits`: each piece must come within
/// [`Limits::body_wait`], or the body ends with an error and `cut` is set.
pub(crate) fn guarded_body(body: Body, limits: Limits, cut: Arc<AtomicBool>) -> Body {
    let start = Instant::now();
    let stream = futures_util::stream::unfold(Some((body, 0u64)), move |st| {
        let (limits, cut) = (limits.clone(), cut.clone());
        async move {
            let (mut body, n) = st?;
            loop {
                let slow = || {
                    cut.store(true, Ordering::SeqCst);
                    let e: axum::BoxError = Box::new(TooSlow);
                    Some((Err(e), None))
                };
                let Some(wait) = limits.body_wait(n, start.elapsed()) else {
                    return slow();
                };
                match tokio::time::timeout(wait, body.frame()).await {
                    Err(_) => return slow(),
                    Ok(None) => return None,
                    Ok(Some(Err(e))) => return Some((Err(e.into()), None)),
                    Ok(Some(Ok(frame))) => {
                        if let Ok(data) = frame.into_data() {
                            let m = n + data.len() as u64;
                            return Some((Ok(data), Some((body, m))));
                        }
                    }
                }
            }
        }
    });
    Body::from_stream(stream)
}

/// Middleware: every request body under [`guarded_body`] with the
/// server's limits (a handler that reads a body cannot be held by one
/// that stalls).
pub(crate) async fn guard_body(
    axum::extract::State(state): axum::extract::State<super::AppState>,
    mut req: Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    let cut = Arc::new(AtomicBool::new(false));
    req.extensions_mut().insert(BodyCut(cut.clone()));
    let limits = state.limits().clone();
    let req = req.map(|b| guarded_body(b, limits, cut));
    next.run(req).await
}

/// What the watchdog of one connection reads.
struct Watch {
    start: Instant,
    /// Milliseconds from `start` of the last byte read or written.
    last_ms: AtomicU64,
    /// Milliseconds from `start` of the first byte of headers not yet
    /// complete ([`NONE`] when none are being read).
    header_ms: AtomicU64,
    /// Requests whose answer is not ready yet.
    in_flight: AtomicUsize,
}

const NONE: u64 = u64::MAX;

impl Watch {
    fn now_ms(&self) -> u64 {
        self.start.elapsed().as_millis() as u64
    }
    fn read_some(&self) {
        let now = self.now_ms();
        self.last_ms.store(now, Ordering::SeqCst);
        if self.in_flight.load(Ordering::SeqCst) == 0 {
            let _ = self
                .header_ms
                .compare_exchange(NONE, now, Ordering::SeqCst, Ordering::SeqCst);
        }
    }
    /// Why the connection is to be closed now, if it is.
    fn expired(&self, limits: &Limits) -> Option<&'static str> {
        let now = self.now_ms();
        let idle = Duration::from_millis(now.saturating_sub(self.last_ms.load(Ordering::SeqCst)));
        if self.in_flight.load(Ordering::SeqCst) > 0 {
            return (idle > limits.check_budget + limits.idle_timeout).then_some("request stalled");
        }
        let h = self.header_ms.load(Ordering::SeqCst);
        if h != NONE && Duration::from_millis(now.saturating_sub(h)) > limits.header_timeout {
            return Some("headers too slow");
        }
        (idle > limits.idle_timeout).then_some("idle")
    }
}

/// A socket whose reads and writes the watchdog sees.
struct Watched {
    io: TcpStream,
    watch: Arc<Watch>,
}

impl AsyncRead for Watched {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        let before = buf.filled().len();
        let r = Pin::new(&mut self.io).poll_read(cx, buf);
        if matches!(r, Poll::Ready(Ok(()))) && buf.filled().len() > before {
            self.watch.read_some();
        }
        r
    }
}

impl AsyncWrite for Watched {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        let r = Pin::new(&mut self.io).poll_write(cx, buf);
        if matches!(r, Poll::Ready(Ok(n)) if n > 0) {
            let now = self.watch.now_ms();
            self.watch.last_ms.store(now, Ordering::SeqCst);
        }
        r
    }
    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_flush(cx)
    }
    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.io).poll_shutdown(cx)
    }
    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        let r = Pin::new(&mut self.io).poll_write_vectored(cx, bufs);
        if matches!(r, Poll::Ready(Ok(n)) if n > 0) {
            let now = self.watch.now_ms();
            self.watch.last_ms.store(now, Ordering::SeqCst);
        }
        r
    }
    fn is_write_vectored(&self) -> bool {
        self.io.is_write_vectored()
    }
}

/// A request in flight on a connection, until its answer is ready.
struct InFlight(Arc<Watch>);

impl Drop for InFlight {
    fn drop(&mut self) {
        let now = self.0.now_ms();
        self.0.last_ms.store(now, Ordering::SeqCst);
        self.0.in_flight.fetch_sub(1, Ordering::SeqCst);
    }
}

/// A connection counted against its address's cap until it ends.
struct AddrSlot {
    map: Arc<Mutex<HashMap<IpAddr, usize>>>,
    ip: IpAddr,
}

impl AddrSlot {
    fn take(map: &Arc<Mutex<HashMap<IpAddr, usize>>>, ip: IpAddr, cap: usize) -> Option<Self> {
        let mut m = map
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let n = m.entry(ip).or_insert(0);
        if *n >= cap {
            return None;
        }
        *n += 1;
        Some(Self {
            map: map.clone(),
            ip,
        })
    }
}

impl Drop for AddrSlot {
    fn drop(&mut self) {
        let mut m = self
            .map
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(n) = m.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                m.remove(&self.ip);
            }
        }
    }
}

/// Answers 503 on a connection past a cap and closes it, reading nothing.
fn refuse(stream: TcpStream, why: &str) {
    let body = format!("{{\"error\":\"{why}; try again in a minute\"}}");
    let head = format!(
        "HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\n\
         content-length: {}\r\nretry-after: 60\r\nconnection: close\r\n\r\n{body}",
        body.len()
    );
    let _ = stream.try_write(head.as_bytes());
}

/// Serves `router` on `listener` under `limits` until the listener fails
/// for good (accept errors such as too many open files are waited out).
pub async fn serve_with_limits(
    listener: TcpListener,
    router: Router,
    limits: Limits,
) -> std::io::Result<()> {
    let all = Arc::new(tokio::sync::Semaphore::new(limits.max_connections.max(1)));
    let per_addr: Arc<Mutex<HashMap<IpAddr, usize>>> = Arc::default();
    loop {
        let (stream, addr) = match listener.accept().await {
            Ok(x) => x,
            Err(e) => {
                tracing::warn!(error = %e, "cannot accept a connection");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let Ok(permit) = all.clone().try_acquire_owned() else {
            refuse(stream, "the server has too many connections open");
            continue;
        };
        let Some(slot) = AddrSlot::take(&per_addr, addr.ip(), limits.max_connections_per_addr)
        else {
            refuse(stream, "too many connections from your address");
            continue;
        };
        let (router, limits) = (router.clone(), limits.clone());
        tokio::spawn(async move {
            connection(stream, addr, router, &limits).await;
            drop((permit, slot));
        });
    }
}

/// One connection, under its watchdog.
async fn connection(stream: TcpStream, addr: SocketAddr, router: Router, limits: &Limits) {
    let _ = stream.set_nodelay(true);
    let watch = Arc::new(Watch {
        start: Instant::now(),
        last_ms: AtomicU64::new(0),
        header_ms: AtomicU64::new(NONE),
        in_flight: AtomicUsize::new(0),
    });
    let w = watch.clone();
    let svc = hyper::service::service_fn(move |req: hyper::Request<hyper::body::Incoming>| {
        w.in_flight.fetch_add(1, Ordering::SeqCst);
        w.header_ms.store(NONE, Ordering::SeqCst);
        let guard = InFlight(w.clone());
        let router = router.clone();
        async move {
            let mut req = req.map(Body::new);
            req.extensions_mut().insert(ConnectInfo(addr));
            let resp = router.oneshot(req).await;
            drop(guard);
            resp
        }
    });
    let io = hyper_util::rt::TokioIo::new(Watched {
        io: stream,
        watch: watch.clone(),
    });
    let conn = hyper::server::conn::http1::Builder::new()
        .timer(hyper_util::rt::TokioTimer::new())
        // hyper's own clock (also between requests) as a backstop of ours.
        .header_read_timeout(limits.header_timeout.max(limits.idle_timeout))
        .serve_connection(io, svc);
    tokio::pin!(conn);
    let tick = (limits.header_timeout.min(limits.idle_timeout) / 4)
        .clamp(Duration::from_millis(10), Duration::from_secs(1));
    loop {
        tokio::select! {
            _ = conn.as_mut() => return,
            _ = tokio::time::sleep(tick) => {
                if watch.expired(limits).is_some() {
                    return;
                }
            }
        }
    }
}
