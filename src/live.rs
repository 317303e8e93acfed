//! The live view (`--live [ADDR]`): a Foxglove WebSocket server (the
//! `foxglove` crate's, protocol `foxglove.sdk.v1`) that carries every
//! channel the recorder writes, as it writes it.
//!
//! Nothing here touches the real-time tick. The recorder's writer thread
//! (non-real-time) logs each message it has just written to the file to
//! the matching live channel as well ([`LiveChannel::log`]); the server
//! sends on its own threads (a tokio runtime the crate starts). A client
//! that reads too slowly has its queue of [`MESSAGE_BACKLOG`] messages cut
//! from the oldest: it is decimated, never waited for. For display, the
//! samples are there twice: `/bench/envelope` (min/max per 5 ms, built on
//! the writer thread) for plots against time, and the `/bench/sample`
//! blocks with every tick.
//!
//! The one-shot channels (one message per run: every `/sysid/…` and
//! `/control/…` topic, e.g. `/sysid/summary`, `/control/metrics`) are
//! latched ([`is_latched`]): a client that subscribes after the message
//! was sent gets the latest one on subscribing, as a ROS latched topic
//! would give it.
//!
//! The server binds to loopback by default ([`DEFAULT_ADDR`]); another
//! address only when given explicitly ([`parse_addr`]).
//!
//! Layer rule: may use nothing of the crate.

use std::net::{IpAddr, SocketAddr};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};

use foxglove::websocket::{ChannelView, Client, ServerListener};
use foxglove::{ChannelBuilder, PartialMetadata, RawChannel, Schema, WebSocketServer};

/// Whether `topic` is a one-shot channel whose latest message a late
/// subscriber gets: every `/sysid/…` and `/control/…` topic (the FRF, the
/// summaries, the loop check, the step metrics, the verification).
pub fn is_latched(topic: &str) -> bool {
    topic.starts_with("/sysid/") || topic.starts_with("/control/")
}

/// A latched message: the channel, the payload and its log time (ns).
type Latched = (Arc<RawChannel>, Vec<u8>, u64);

/// The latest message of each latched channel. Written by the recorder's
/// writer thread, read by the server's thread when a client subscribes;
/// never by the loop.
static LATCHED: Mutex<Vec<Latched>> = Mutex::new(Vec::new());

/// Gives a new subscriber of a latched channel its latest message.
struct Latch;

impl ServerListener for Latch {
    fn on_subscribe(&self, client: Client, channel: ChannelView) {
        let latched = LATCHED.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((ch, data, t)) = latched.iter().find(|(c, _, _)| c.id() == channel.id()) {
            ch.log_with_meta_to_sink(data, PartialMetadata::with_log_time(*t), client.sink_id());
        }
    }
}

/// The default address of the live view: loopback only.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8765";

/// Messages queued per client before the oldest are dropped.
pub const MESSAGE_BACKLOG: usize = 1024;

/// Set once a server runs in this process: recorders then mirror their
/// channels.
static SERVING: AtomicBool = AtomicBool::new(false);

/// Errors of the live view.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// The `--live` argument is not `IP:PORT`.
    #[error("--live {given:?}: {reason}")]
    Address {
        /// What was given.
        given: String,
        /// Why it is refused.
        reason: String,
    },
    /// The server could not start (e.g. the port is taken).
    #[error("--live {addr}: cannot start the live view: {reason}")]
    Start {
        /// The address.
        addr: SocketAddr,
        /// Why.
        reason: String,
    },
}

/// Parses `--live`'s value: an IP address and a port, `IP:PORT` (IPv6 as
/// `[IP]:PORT`). Host names are refused (an explicit address says which
/// interface is exposed); port 0 lets the OS choose (the chosen port is
/// printed).
///
/// # Errors
/// [`LiveError::Address`] naming the value and the reason.
pub fn parse_addr(given: &str) -> Result<SocketAddr, LiveError> {
    given.parse::<SocketAddr>().map_err(|_| LiveError::Address {
        given: given.to_string(),
        reason: "expected IP:PORT, e.g. 127.0.0.1:8765 (loopback, the default) or \
                 0.0.0.0:8765 to serve every interface; host names are not accepted"
            .into(),
    })
}

/// How long a stopping live view waits for its clients' close handshakes.
pub const CLOSE_WAIT: std::time::Duration = std::time::Duration::from_secs(2);

/// A running live view; stops when dropped.
pub struct LiveServer {
    handle: Option<foxglove::WebSocketServerHandle>,
    addr: SocketAddr,
    /// Ends the server's thread when sent (or dropped): with the server's
    /// shutdown handle, once its clients are closed (at most
    /// [`CLOSE_WAIT`]).
    shutdown: Option<tokio::sync::oneshot::Sender<Option<foxglove::websocket::ShutdownHandle>>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl std::fmt::Debug for LiveServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveServer")
            .field("addr", &self.addr)
            .finish()
    }
}

impl LiveServer {
    /// Starts the server on `addr`; from now on every recorder created in
    /// this process mirrors its channels to it.
    ///
    /// The server runs on one thread of its own (`bench-live`, a
    /// single-threaded tokio runtime) at nice 10, kept off `loop_cpu` (the
    /// CPU the real-time loop is pinned to, `loop.cpu`) when the machine
    /// has another: its sends, and the loopback network work the kernel
    /// does for them on the sending CPU, stay away from the loop.
    ///
    /// # Errors
    /// [`LiveError::Start`] when it cannot bind or start.
    pub fn start(addr: SocketAddr, loop_cpu: Option<usize>) -> Result<Self, LiveError> {
        let fail = |reason: String| LiveError::Start { addr, reason };
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| fail(e.to_string()))?;
        let handle = rt.handle().clone();
        let (tx, rx) =
            tokio::sync::oneshot::channel::<Option<foxglove::websocket::ShutdownHandle>>();
        let thread = std::thread::Builder::new()
            .name("bench-live".into())
            .spawn(move || {
                bench_hal::os::keep_off_cpu(loop_cpu);
                // Drives the server's tasks until shutdown, then lets them
                // send every client its close frame (RFC 6455 §7: code 1001,
                // going away) before the runtime ends; a client that does
                // not answer is cut off after CLOSE_WAIT.
                if let Ok(Some(closing)) = rt.block_on(rx) {
                    rt.block_on(async {
                        let _ = tokio::time::timeout(CLOSE_WAIT, closing.wait()).await;
                    });
                }
            })
            .map_err(|e| fail(e.to_string()))?;
        let server = WebSocketServer::new()
            .name(concat!("bench ", env!("CARGO_PKG_VERSION")))
            .bind(addr.ip().to_string(), addr.port())
            .message_backlog_size(MESSAGE_BACKLOG)
            .listener(Arc::new(Latch))
            .tokio_runtime(&handle)
            .start_blocking();
        let mut live = Self {
            handle: None,
            addr,
            shutdown: Some(tx),
            thread: Some(thread),
        };
        let server = server.map_err(|e| fail(e.to_string()))?;
        live.addr = SocketAddr::new(addr.ip(), server.port());
        live.handle = Some(server);
        SERVING.store(true, Ordering::Release);
        Ok(live)
    }

    /// The address served (with the port the OS chose for port 0).
    pub fn addr(&self) -> SocketAddr {
        self.addr
    }

    /// The URL to open in Foxglove (*Open connection* → *Foxglove
    /// WebSocket*).
    pub fn url(&self) -> String {
        let host = match self.addr.ip() {
            IpAddr::V6(ip) => format!("[{ip}]"),
            IpAddr::V4(ip) => ip.to_string(),
        };
        format!("ws://{host}:{}", self.addr.port())
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        self.handle.as_ref().map_or(0, |h| h.client_count())
    }
}

impl Drop for LiveServer {
    fn drop(&mut self) {
        SERVING.store(false, Ordering::Release);
        // The server's tasks end on the runtime thread, still running:
        // it waits for them (dropping the handle would abort them, and
        // every client would see the connection reset, close code 1006).
        let closing = self.handle.take().map(|h| h.stop());
        if let Some(tx) = self.shutdown.take() {
            let _ = tx.send(closing);
        }
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Which clients the live view serves, and which it refuses: what the log
/// says when a client's handshake fails ([`refused_handshake`]) and the
/// README says in *Live view*. The `foxglove` crate (0.30) negotiates only
/// `foxglove.sdk.v1` and `foxglove.sdk.v1.1`
/// (`websocket::handshake::Subprotocol::from_name`, crate-private): no
/// option of its `WebSocketServer` builder and no [`ServerListener`]
/// callback sees the handshake (the listener's first call,
/// `on_client_connect`, comes after it), so `foxglove.websocket.v1` cannot
/// be added; the crate answers such a client HTTP 400.
pub const CLIENTS: &str = "the live view speaks the Foxglove WebSocket subprotocols foxglove.sdk.v1 and foxglove.sdk.v1.1 only: the foxglove crate it is built on (0.30) negotiates nothing else and has no option to, so a client that offers only foxglove.websocket.v1 gets HTTP 400. Refused: Lichtblick before 1.22.0, Foxglove apps from before the Foxglove SDK, and clients built on @foxglove/ws-protocol or written to its foxglove.websocket.v1 spec (the foxglove-websocket Python package is a server and has no client). Served: the Foxglove app, Lichtblick 1.22.0 or later (PR #819), and any client that offers foxglove.sdk.v1, whose messages are those of foxglove.websocket.v1";

/// The address of the client whose handshake the `foxglove` crate's
/// server refused, if `event` is its log line (`Dropping client ADDR:
/// handshake failed`, target `foxglove::websocket…`). The crate does not
/// say why; a handshake fails when the client offers none of the
/// subprotocols it speaks (see [`CLIENTS`]) or is not a WebSocket
/// handshake at all. For the CLI's log, which says [`CLIENTS`] instead.
pub fn refused_handshake(event: &tracing::Event<'_>) -> Option<String> {
    if !event.metadata().target().starts_with("foxglove::websocket") {
        return None;
    }
    struct Message(Option<String>);
    impl tracing::field::Visit for Message {
        fn record_str(&mut self, field: &tracing::field::Field, value: &str) {
            if field.name() == "message" {
                self.0 = Some(value.to_string());
            }
        }
        fn record_debug(&mut self, field: &tracing::field::Field, value: &dyn std::fmt::Debug) {
            if field.name() == "message" {
                self.0 = Some(format!("{value:?}"));
            }
        }
    }
    let mut m = Message(None);
    event.record(&mut m);
    let text = m.0?;
    let addr = text
        .strip_prefix("Dropping client ")?
        .strip_suffix(": handshake failed")?;
    Some(addr.to_string())
}

/// The log line of a refused handshake (see [`refused_handshake`]).
pub fn refusal_message(addr: &str) -> String {
    format!("live view: refused the client at {addr}: its WebSocket handshake offered no subprotocol this server speaks (or was no WebSocket handshake); {CLIENTS} (docs/src/live.md)")
}

/// One recorder channel's live twin.
#[derive(Clone)]
pub struct LiveChannel(Arc<RawChannel>);

impl std::fmt::Debug for LiveChannel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_tuple("LiveChannel").field(&self.0.topic()).finish()
    }
}

impl LiveChannel {
    /// The live twin of a recorder channel, `None` when no live view runs
    /// (or the crate refuses the channel). A channel with the same topic,
    /// encoding and schema as an earlier one (the next job of `bench
    /// serve`) is that channel: clients stay subscribed across jobs.
    pub fn new(
        topic: &str,
        message_encoding: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema_data: &[u8],
    ) -> Option<Self> {
        if !SERVING.load(Ordering::Acquire) {
            return None;
        }
        ChannelBuilder::new(topic)
            .message_encoding(message_encoding)
            .schema(Schema::new(
                schema_name,
                schema_encoding,
                schema_data.to_vec(),
            ))
            .build_raw()
            .ok()
            .map(Self)
    }

    /// Sends `data` (already encoded as the channel says) with `log_time`
    /// (ns since the Unix epoch) to the subscribed clients. Never blocks: a
    /// client whose queue is full loses its oldest messages.
    pub fn log(&self, data: &[u8], log_time_ns: u64) {
        if is_latched(self.0.topic()) {
            let mut latched = LATCHED.lock().unwrap_or_else(|e| e.into_inner());
            let entry = (self.0.clone(), data.to_vec(), log_time_ns);
            match latched.iter_mut().find(|(c, _, _)| c.id() == self.0.id()) {
                Some(e) => *e = entry,
                None => latched.push(entry),
            }
        }
        self.0
            .log_with_meta(data, PartialMetadata::with_log_time(log_time_ns));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn addresses_are_ip_and_port_only() {
        assert_eq!(
            parse_addr(DEFAULT_ADDR).unwrap(),
            "127.0.0.1:8765".parse().unwrap()
        );
        assert!(parse_addr("[::1]:9000").is_ok());
        for bad in [
            "",
            "localhost:8765",
            "127.0.0.1",
            "127.0.0.1:",
            "127.0.0.1:65536",
            "127.0.0.1:-1",
            "8765",
            "ws://127.0.0.1:8765",
            "256.0.0.1:80",
        ] {
            let e = parse_addr(bad).unwrap_err().to_string();
            assert!(e.contains("--live") && e.contains("IP:PORT"), "{bad}: {e}");
        }
    }
}
