//! The local API server: a Unix socket (mode 0660) where each client gets every event line and
//! may send commands, one reply line each (docs/api.md).
//!
//! One hub task owns the clients and a mirror [`ConsoleState`]: it applies each broadcast event
//! to the mirror and hands the line to every client's bounded queue without waiting. A new client
//! gets `hello` and a snapshot of the mirror first, in the same task, so nothing falls between
//! the snapshot and the live events. A client whose queue is full misses lines and gets one
//! `{"event":"lagged","missed":N}` when it has room again: a slow client never stalls the
//! operator or the other clients.
//!
//! Each client task reads bounded lines ([`MAX_LINE_BYTES`]), parses them, forwards commands
//! over the same [`CommandRequest`] channel the console uses and writes the operator's answer.
//! Malformed input gets a JSON error reply and the connection stays open.

use crate::api::{
    ApiReply, MAX_LINE_BYTES, event_json, hello_json, lagged_json, parse_command_bytes,
    standing_json,
};
use crate::command::{CommandRequest, Source};
use crate::error::{ApiError, Result};
use crate::model::{ConsoleState, Stamped};
use rove_core::msg::DeviceId;
use std::os::unix::fs::{FileTypeExt, PermissionsExt};
use std::path::{Path, PathBuf};
use std::time::Duration;
use tokio::io::{AsyncBufRead, AsyncBufReadExt, AsyncWriteExt, BufReader};
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::{broadcast, mpsc, oneshot};
use tracing::{debug, warn};

/// Socket file mode: owner and group read/write, nobody else. Put the users of a front end in
/// the operator's group; anyone who can connect can drive.
pub const SOCKET_MODE: u32 = 0o660;

/// Lines queued per client before it counts as lagging: a full snapshot of a large fleet
/// (a few lines per device) plus a burst of events; more only delays the `lagged` notice.
pub const CLIENT_QUEUE: usize = 1024;

/// Most clients at once: front ends are a handful; the bound keeps a runaway client script from
/// exhausting file descriptors of the operator.
pub const MAX_CLIENTS: usize = 64;

/// How long a client waits for the operator to answer a command before it gets a `timeout`
/// error: the operator answers within one event-loop turn; seconds mean it is stuck.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(5);

/// A bound API socket. Dropping it removes the socket file.
#[derive(Debug)]
pub struct ApiSocket {
    listener: UnixListener,
    path: PathBuf,
}

impl ApiSocket {
    /// Binds `path` with mode 0660. A stale socket file (nobody listening) is removed first.
    /// Must be called inside a tokio runtime.
    ///
    /// # Errors
    /// [`ApiError::NotASocket`] if the path is some other file, [`ApiError::InUse`] if a
    /// process listens on it, [`ApiError::Socket`] if removing, binding or `chmod` fails.
    pub fn bind(path: &Path) -> Result<ApiSocket> {
        let socket_err = |source| ApiError::Socket {
            path: path.to_path_buf(),
            source,
        };
        match std::fs::symlink_metadata(path) {
            Ok(meta) if meta.file_type().is_socket() => {
                if std::os::unix::net::UnixStream::connect(path).is_ok() {
                    return Err(ApiError::InUse {
                        path: path.to_path_buf(),
                    });
                }
                std::fs::remove_file(path).map_err(socket_err)?;
            }
            Ok(_) => {
                return Err(ApiError::NotASocket {
                    path: path.to_path_buf(),
                });
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(e) => return Err(socket_err(e)),
        }
        let listener = UnixListener::bind(path).map_err(socket_err)?;
        // From here on the file is ours: Drop removes it, also if chmod fails.
        let socket = ApiSocket {
            listener,
            path: path.to_path_buf(),
        };
        std::fs::set_permissions(path, std::fs::Permissions::from_mode(SOCKET_MODE))
            .map_err(socket_err)?;
        Ok(socket)
    }

    /// The socket's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Serves clients from `hub` until the hub stops (the operator dropped its events).
    /// Commands go to `commands`.
    ///
    /// # Errors
    /// None today; the `Result` leaves room for fatal listener errors.
    pub async fn serve(self, hub: Hub, commands: mpsc::Sender<CommandRequest>) -> Result<()> {
        let mut next_id = 0u64;
        loop {
            let accepted = tokio::select! {
                accepted = self.listener.accept() => accepted,
                () = hub.stopped() => return Ok(()),
            };
            match accepted {
                Ok((stream, _)) => {
                    next_id += 1;
                    match hub.join().await {
                        Joined::Lines(rx) => {
                            debug!(client = next_id, "API client connected");
                            tokio::spawn(client_task(stream, rx, commands.clone(), next_id));
                        }
                        Joined::Busy => {
                            warn!("API: too many clients, refusing one");
                            tokio::spawn(refuse_client(stream));
                        }
                        Joined::Stopped => return Ok(()),
                    }
                }
                Err(e) => {
                    // EMFILE and the like: back off instead of spinning on the error.
                    warn!(cause = %e, "API: accept failed");
                    tokio::time::sleep(Duration::from_millis(100)).await;
                }
            }
        }
    }
}

/// What joining the [`Hub`] gives.
#[derive(Debug)]
pub enum Joined {
    /// The client's lines: `hello`, the snapshot, then every event, in order.
    Lines(mpsc::Receiver<String>),
    /// [`MAX_CLIENTS`] are connected.
    Busy,
    /// The operator stopped.
    Stopped,
}

/// The event hub of one operator, whatever the transport of its clients (the local API's Unix
/// socket, the browser console's WebSocket). Cheap to clone.
#[derive(Debug, Clone)]
pub struct Hub {
    joins: mpsc::Sender<oneshot::Sender<Joined>>,
}

impl Hub {
    /// Starts the hub task. `mirror` is the state before the first event received here
    /// (usually `ConsoleState::new`); the hub stops when `events` closes. Must be called inside
    /// a tokio runtime.
    pub fn start(mirror: ConsoleState, events: broadcast::Receiver<Stamped>) -> Hub {
        let (joins, rx) = mpsc::channel(16);
        tokio::spawn(hub_task(mirror, events, rx));
        Hub { joins }
    }

    /// Completes when the hub has stopped (the operator's events closed).
    pub async fn stopped(&self) {
        self.joins.closed().await;
    }

    /// A new client's lines, or why not.
    pub async fn join(&self) -> Joined {
        let (tx, rx) = oneshot::channel();
        if self.joins.send(tx).await.is_err() {
            return Joined::Stopped;
        }
        rx.await.unwrap_or(Joined::Stopped)
    }
}

async fn hub_task(
    mut mirror: ConsoleState,
    mut events: broadcast::Receiver<Stamped>,
    mut joins: mpsc::Receiver<oneshot::Sender<Joined>>,
) {
    let mut clients: Vec<Client> = Vec::new();
    let offline_after_ms = u64::try_from(mirror.offline_after.as_millis()).unwrap_or(u64::MAX);
    // Each vehicle's standing as last sent: a change (from any event, or time) goes out once.
    let mut standings = Standings::default();
    loop {
        tokio::select! {
            Some(join) = joins.recv() => {
                clients.retain(|c| !c.tx.is_closed());
                if clients.len() >= MAX_CLIENTS {
                    let _ = join.send(Joined::Busy);
                    continue;
                }
                let (tx, rx) = mpsc::channel(CLIENT_QUEUE);
                let mut client = Client { tx, missed: 0 };
                client.deliver(hello_json(mirror.now, offline_after_ms));
                for stamped in mirror.snapshot() {
                    if let Some(line) = event_json(&stamped) {
                        client.deliver(line);
                    }
                }
                for line in standings.all(&mirror) {
                    client.deliver(line);
                }
                if join.send(Joined::Lines(rx)).is_ok() {
                    clients.push(client);
                }
            }
            event = events.recv() => match event {
                Ok(stamped) => {
                    let line = event_json(&stamped);
                    // Input reports come at the stream rate and move no vehicle's standing.
                    let input = matches!(stamped.event, crate::model::Event::Input(_));
                    mirror.apply(stamped.at, stamped.event);
                    let changed = if input { Vec::new() } else { standings.changed(&mirror) };
                    for line in line.into_iter().chain(changed) {
                        clients.retain_mut(|c| c.deliver(line.clone()));
                    }
                }
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    // The hub itself fell behind: every client missed these, and the
                    // mirror may be stale until the next DeviceInfo refreshes (5 s; a missed
                    // `device_gone` until the 15 s backstop).
                    warn!(missed = n, "API hub lagged behind the operator's events");
                    for c in &mut clients {
                        c.missed = c.missed.saturating_add(n);
                    }
                }
                Err(broadcast::error::RecvError::Closed) => return,
            },
        }
    }
}

/// The `standing` of each vehicle as last sent to clients ([`mod@crate::standing`]).
#[derive(Default)]
struct Standings {
    sent: std::collections::BTreeMap<DeviceId, String>,
}

impl Standings {
    /// Every vehicle's `standing` line now (for a client that just joined).
    fn all(&self, state: &ConsoleState) -> Vec<String> {
        (state.vehicles())
            .filter_map(|d| Some((d.id, state.standing_text(d.id)?)))
            .map(|(v, (s, text))| standing_json(state.now, v, &s, &text))
            .collect()
    }

    /// The `standing` lines of the vehicles whose standing changed since last sent.
    fn changed(&mut self, state: &ConsoleState) -> Vec<String> {
        let mut lines = Vec::new();
        for d in state.vehicles() {
            let Some((s, text)) = state.standing_text(d.id) else {
                continue;
            };
            if self.sent.get(&d.id) != Some(&text) {
                lines.push(standing_json(state.now, d.id, &s, &text));
                self.sent.insert(d.id, text);
            }
        }
        self.sent.retain(|id, _| state.devices.contains_key(id));
        lines
    }
}

impl Drop for ApiSocket {
    fn drop(&mut self) {
        let ours = std::fs::symlink_metadata(&self.path).is_ok_and(|m| m.file_type().is_socket());
        if ours && let Err(e) = std::fs::remove_file(&self.path) {
            warn!(path = %self.path.display(), cause = %e, "cannot remove API socket");
        }
    }
}

/// The hub's handle on one client.
struct Client {
    tx: mpsc::Sender<String>,
    /// Lines dropped since the last one delivered.
    missed: u64,
}

impl Client {
    /// Queues `line` without waiting; false once the client is gone.
    fn deliver(&mut self, line: String) -> bool {
        use mpsc::error::TrySendError;
        if self.missed > 0 {
            match self.tx.try_send(lagged_json(self.missed)) {
                Ok(()) => self.missed = 0,
                Err(TrySendError::Full(_)) => {
                    self.missed = self.missed.saturating_add(1);
                    return true;
                }
                Err(TrySendError::Closed(_)) => return false,
            }
        }
        match self.tx.try_send(line) {
            Ok(()) => true,
            Err(TrySendError::Full(_)) => {
                self.missed = self.missed.saturating_add(1);
                true
            }
            Err(TrySendError::Closed(_)) => false,
        }
    }
}

async fn refuse_client(mut stream: UnixStream) {
    let reply = ApiReply::Error {
        error: format!("too many clients (at most {MAX_CLIENTS})"),
        code: "busy",
        line: None,
    };
    let _ = stream
        .write_all(format!("{}\n", reply.to_json()).as_bytes())
        .await;
}

async fn client_task(
    stream: UnixStream,
    mut lines: mpsc::Receiver<String>,
    commands: mpsc::Sender<CommandRequest>,
    id: u64,
) {
    let (read, mut write) = stream.into_split();
    let mut reader = LineReader::new(BufReader::new(read));
    let mut line_no = 0u64;
    loop {
        let out = tokio::select! {
            line = lines.recv() => match line {
                Some(line) => line,
                None => return, // the hub is gone: the operator is stopping
            },
            read = reader.next_line() => match read {
                Ok(Some(raw)) => {
                    line_no += 1;
                    if raw.as_ref().is_ok_and(|l| l.trim_ascii().is_empty()) {
                        continue;
                    }
                    answer(raw, line_no, &commands, Source::Api(id)).await.to_json()
                }
                Ok(None) => return,
                Err(e) => {
                    debug!(client = id, cause = %e, "API client read failed");
                    return;
                }
            },
        };
        let mut out = out.into_bytes();
        out.push(b'\n');
        if write.write_all(&out).await.is_err() {
            return;
        }
    }
}

/// The reply to one command line (`raw`, or why it could not be read) from `source`: parsed,
/// carried out by the operator through `commands`, answered within [`REPLY_TIMEOUT`].
pub async fn answer(
    raw: std::result::Result<Vec<u8>, ApiError>,
    line: u64,
    commands: &mpsc::Sender<CommandRequest>,
    source: Source,
) -> ApiReply {
    let command = match raw.and_then(|raw| parse_command_bytes(&raw)) {
        Ok(c) => c,
        Err(e) => return ApiReply::parse_error(&e, line),
    };
    let unavailable = ApiReply::Error {
        error: "the operator is not taking commands (stopping?)".into(),
        code: "unavailable",
        line: Some(line),
    };
    let (reply, answer) = oneshot::channel();
    let request = CommandRequest {
        command,
        source,
        reply,
    };
    if commands.send(request).await.is_err() {
        return unavailable;
    }
    match tokio::time::timeout(REPLY_TIMEOUT, answer).await {
        Ok(Ok(Ok(()))) => ApiReply::Ok,
        Ok(Ok(Err(why))) => ApiReply::Error {
            error: why,
            code: "refused",
            line: Some(line),
        },
        Ok(Err(_)) => unavailable,
        Err(_) => ApiReply::Error {
            error: format!("no answer from the operator within {REPLY_TIMEOUT:?}"),
            code: "timeout",
            line: Some(line),
        },
    }
}

/// Reads newline-terminated lines of at most [`MAX_LINE_BYTES`], skipping the rest of a longer
/// one. Cancel-safe: its state lives in the struct, and it only awaits `fill_buf`, which
/// consumes nothing, so a `select!` may drop `next_line` at any point without losing bytes.
struct LineReader<R> {
    inner: R,
    buf: Vec<u8>,
    /// Inside a line that went over the limit: drop bytes up to its newline.
    skipping: bool,
}

impl<R: AsyncBufRead + Unpin> LineReader<R> {
    fn new(inner: R) -> Self {
        LineReader {
            inner,
            buf: Vec::new(),
            skipping: false,
        }
    }

    /// The next line (without newline), an [`ApiError::TooLong`] for an over-long one, or
    /// `None` at end of stream.
    async fn next_line(
        &mut self,
    ) -> std::io::Result<Option<std::result::Result<Vec<u8>, ApiError>>> {
        loop {
            let available = self.inner.fill_buf().await?;
            if available.is_empty() {
                // End of stream: a last line without newline still counts.
                return Ok(match (self.skipping, self.buf.is_empty()) {
                    (true, _) => {
                        self.skipping = false;
                        Some(Err(ApiError::TooLong {
                            max: MAX_LINE_BYTES,
                        }))
                    }
                    (false, true) => None,
                    (false, false) => Some(Ok(std::mem::take(&mut self.buf))),
                });
            }
            let newline = available.iter().position(|&b| b == b'\n');
            let part = &available[..newline.unwrap_or(available.len())];
            if !self.skipping {
                if self.buf.len() + part.len() > MAX_LINE_BYTES {
                    self.skipping = true;
                    self.buf = Vec::new();
                } else {
                    self.buf.extend_from_slice(part);
                }
            }
            let used = part.len() + usize::from(newline.is_some());
            self.inner.consume(used);
            if newline.is_some() {
                let line = if std::mem::take(&mut self.skipping) {
                    Err(ApiError::TooLong {
                        max: MAX_LINE_BYTES,
                    })
                } else {
                    Ok(std::mem::take(&mut self.buf))
                };
                return Ok(Some(line));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::command::Command;
    use crate::model::tests::{me, ms, seen};
    use crate::model::{DeviceKind, Event, Stamped};
    use serde_json::Value;
    use tokio::io::Lines;
    use tokio::io::{AsyncBufReadExt, AsyncWriteExt};
    use tokio::net::unix::OwnedReadHalf;

    type Reader = Lines<BufReader<OwnedReadHalf>>;

    /// Reads lines until one satisfies `want`, with a deadline (no fixed sleeps).
    async fn until(reader: &mut Reader, want: impl Fn(&Value) -> bool) -> Value {
        let deadline = Duration::from_secs(5);
        let read = async {
            loop {
                let line = reader.next_line().await.expect("read").expect("line");
                let v: Value = serde_json::from_str(&line).expect("every line is JSON");
                if want(&v) {
                    return v;
                }
            }
        };
        tokio::time::timeout(deadline, read).await.expect("in time")
    }

    /// A fake operator: answers drive commands for vehicle 100 with ok, others with a refusal.
    fn fake_operator(mut rx: mpsc::Receiver<CommandRequest>) {
        tokio::spawn(async move {
            while let Some(req) = rx.recv().await {
                let answer = match req.command {
                    Command::Drive { vehicle: 100 } => Ok(()),
                    other => Err(format!("cannot {}", other.name())),
                };
                let _ = req.reply.send(answer);
            }
        });
    }

    #[tokio::test]
    async fn serves_events_commands_and_errors_over_a_0660_socket() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("api.sock");
        let socket = ApiSocket::bind(&path).expect("bind");
        let mode = std::fs::metadata(&path)
            .expect("socket file")
            .permissions()
            .mode();
        assert_eq!(mode & 0o777, 0o660);

        let (events_tx, events_rx) = broadcast::channel(64);
        let (cmd_tx, cmd_rx) = mpsc::channel(8);
        fake_operator(cmd_rx);
        let mut mirror = ConsoleState::new(me(), Duration::from_secs(3));
        mirror.apply(ms(0), seen(100, "rover-1", DeviceKind::Vehicle, 100));
        let server = tokio::spawn(socket.serve(Hub::start(mirror, events_rx), cmd_tx));

        let stream = UnixStream::connect(&path).await.expect("connect");
        let (read, mut write) = stream.into_split();
        let mut reader = BufReader::new(read).lines();
        let hello = until(&mut reader, |v| v["event"] == "hello").await;
        assert_eq!(hello["version"], 1);
        assert_eq!(hello["offline_after_ms"], 3000);
        // The snapshot names the vehicle seen before we connected.
        let dev = until(&mut reader, |v| v["event"] == "device").await;
        assert_eq!(dev["id"], 100);
        assert_eq!(dev["owner"], 100);

        let sent = [
            "{\"cmd\":\"drive\",\"vehicle\":100}\n".to_string(),
            "this is not json\n".to_string(),
            "\n".to_string(),
            "{\"cmd\":\"fly\"}\n".to_string(),
            "{\"cmd\":\"request\",\"vehicle\":101}\n".to_string(),
            format!("{}\n", "x".repeat(MAX_LINE_BYTES + 10)),
            "{\"cmd\":\"drive\"}\n".to_string(),
        ];
        for line in &sent {
            write.write_all(line.as_bytes()).await.expect("write");
        }
        let is_reply = |v: &Value| v.get("ok").is_some() || v.get("error").is_some();
        let mut replies = Vec::new();
        for _ in 0..6 {
            replies.push(until(&mut reader, is_reply).await);
        }
        assert_eq!(replies[0], serde_json::json!({"ok": true}));
        assert_eq!(replies[1]["code"], "bad_json");
        assert_eq!(replies[1]["line"], 2);
        assert_eq!(replies[2]["code"], "unknown_cmd");
        assert_eq!(replies[2]["line"], 4, "the blank line 3 gets no reply");
        assert_eq!(replies[3]["code"], "refused");
        assert_eq!(replies[3]["error"], "cannot request");
        assert_eq!(replies[4]["code"], "too_long");
        assert_eq!(replies[5]["code"], "missing_field");

        // Events broadcast by the operator arrive, with their time.
        let _ = events_tx.send(Stamped {
            at: ms(2_000),
            event: Event::OwnerChanged {
                vehicle: 100,
                from: 100,
                to: 1,
                reason: "you started driving".into(),
            },
        });
        let owner = until(&mut reader, |v| v["event"] == "owner").await;
        assert_eq!(owner["to"], 1);
        assert_eq!(owner["reason"], "you started driving");
        assert_eq!(owner["t_ms"], 2_000);

        // A client that connects now sees the new owner in its snapshot.
        let late = UnixStream::connect(&path).await.expect("connect");
        // Keep the write half: closing it ends the session (after any replies).
        let (late, _late_write) = late.into_split();
        let mut late = BufReader::new(late).lines();
        let dev = until(&mut late, |v| v["event"] == "device").await;
        assert_eq!(dev["owner"], 1);

        // The operator stops: the server ends and removes its socket.
        drop(events_tx);
        let ended = tokio::time::timeout(Duration::from_secs(5), server).await;
        assert!(matches!(ended, Ok(Ok(Ok(())))));
        assert!(!path.exists());
    }

    #[tokio::test]
    async fn a_slow_client_gets_lagged_instead_of_stalling_the_operator() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("api.sock");
        let socket = ApiSocket::bind(&path).expect("bind");
        let (events_tx, events_rx) = broadcast::channel(8192);
        let (cmd_tx, _cmd_rx) = mpsc::channel(8);
        let mirror = ConsoleState::new(me(), Duration::from_secs(3));
        tokio::spawn(socket.serve(Hub::start(mirror, events_rx), cmd_tx));
        let stream = UnixStream::connect(&path).await.expect("connect");
        let (read, _write) = stream.into_split();
        let mut reader = BufReader::new(read).lines();
        until(&mut reader, |v| v["event"] == "hello").await;
        // Far more than the queue and the socket buffer hold, while we do not read.
        let text = "n".repeat(1000);
        for i in 0..5_000u64 {
            let _ = events_tx.send(Stamped {
                at: ms(i),
                event: Event::Notice { text: text.clone() },
            });
        }
        let _ = events_tx.send(Stamped {
            at: ms(9_999),
            event: Event::Notice {
                text: "last".into(),
            },
        });
        let lagged = until(&mut reader, |v| v["event"] == "lagged").await;
        assert!(lagged["missed"].as_u64().is_some_and(|n| n > 0), "{lagged}");
    }

    #[tokio::test]
    async fn refuses_to_replace_a_file_or_a_live_socket_and_replaces_a_stale_one() {
        let dir = tempfile::tempdir().expect("tempdir");
        let file = dir.path().join("not-a-socket");
        std::fs::write(&file, "keep me").expect("write");
        assert!(matches!(
            ApiSocket::bind(&file),
            Err(ApiError::NotASocket { .. })
        ));
        assert_eq!(
            std::fs::read_to_string(&file).ok().as_deref(),
            Some("keep me")
        );

        let path = dir.path().join("api.sock");
        let live = ApiSocket::bind(&path).expect("bind");
        assert!(matches!(
            ApiSocket::bind(&path),
            Err(ApiError::InUse { .. })
        ));
        drop(live);
        // A stale socket file: bound by a std listener that is gone, file left behind.
        let stale = std::os::unix::net::UnixListener::bind(&path).expect("bind");
        drop(stale);
        assert!(path.exists());
        let again = ApiSocket::bind(&path);
        assert!(again.is_ok(), "{again:?}");

        let missing = dir.path().join("no-such-dir").join("api.sock");
        assert!(matches!(
            ApiSocket::bind(&missing),
            Err(ApiError::Socket { .. })
        ));
    }

    #[tokio::test]
    async fn line_reader_bounds_lines_and_keeps_going() {
        let long = vec![b'x'; MAX_LINE_BYTES + 1];
        let mut input = b"a\n".to_vec();
        input.extend_from_slice(&long);
        input.extend_from_slice(b"\nb\nexact");
        let mut reader = LineReader::new(BufReader::with_capacity(7, &input[..]));
        let mut got = Vec::new();
        while let Some(line) = reader.next_line().await.expect("read") {
            got.push(line.map_err(|e| e.code()));
        }
        assert_eq!(
            got,
            [
                Ok(b"a".to_vec()),
                Err("too_long"),
                Ok(b"b".to_vec()),
                Ok(b"exact".to_vec())
            ]
        );
    }
}
