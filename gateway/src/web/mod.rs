//! The browser operator console (`[web]`, docs/web.md): an HTTPS page that phones and tablets
//! pair with once and then drive from, with touch sticks or a gamepad.
//!
//! **Each paired browser is an operator device with a DDS participant of its own.** The trust
//! rules pin a device id to one participant (docs/design.md §4b), a secured fleet grants ids per
//! certificate, and a vehicle's arbiter ranks writers by strength: a browser that is its own
//! participant, with its own id, strength and writers, needs none of those rules bent. The host
//! participant speaking for several ids would have made every vehicle and operator accept one
//! participant as several devices. The cost is one participant (two rustdds threads) per
//! connected browser: the device's participant starts when its browser connects and leaves
//! [`LINGER`] after its last connection closed, so a device is online only while used.
//!
//! Each device runs the same operator loop as `rove operator` ([`crate::operator`]) with the
//! browser as its input ([`WebInput`]) and the page as its console: the page gets the local
//! API's events and sends its commands (docs/api.md) over a WebSocket, with input frames at the
//! stream rate in between. Stale-input safety is [`rove_core::remote::RemoteInput`]'s: a
//! hidden page, a lifted finger, a closed socket or 200 ms of silence release at once, and
//! driving resumes only through centred sticks.
//!
//! # Layout
//! - this file: the HTTPS server, pairing and the WebSocket protocol.
//! - `device.rs`: a web device — its operator loop (with injected edges, [`crate::operator`])
//!   started and stopped, and [`WebInput`], the browser's sticks.
//! - `protocol.rs`: what a page's WebSocket message is ([`page_message`], pure).
//! - [`pairing`]: one-time codes and session tokens (pure).
//! - [`tls`]: the page's certificate, loaded or made.

mod device;
pub mod pairing;
mod protocol;
pub mod tls;

pub use device::WebInput;
use device::{Running, reap, start_device, stop_device};
pub use protocol::{MAX_REASON, PageMessage, page_message};

use crate::config::{OperatorConfig, WebConfig};
use crate::operator::Options;
use crate::runtime::Clock;
use axum::extract::State;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use pairing::Pairing;
use rove_console::server::answer;
use rove_console::{CommandRequest, Event, Joined, Source};
use serde_json::json;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::sync::{Notify, broadcast, mpsc, watch};
use tracing::{debug, info, warn};

/// A browser silent this long has lost its link: its vehicles are released at once. Ten frames
/// at the page's 50 Hz; a background tab's timers run at 1 Hz at most, so a hidden page is
/// caught by this too if its `visibilitychange` never arrived.
pub const SILENCE: Duration = Duration::from_millis(200);

/// How long a device's participant stays after its last browser connection closed: a page
/// reload or a short radio drop reconnects to the same participant at once (already matched by
/// every vehicle); a browser that went away for good leaves the device lists after this.
pub const LINGER: Duration = Duration::from_secs(10);

/// The first message (the token) must come within this.
const AUTH_WAIT: Duration = Duration::from_secs(5);

/// Largest WebSocket message or pairing request taken: a command or frame is under 200 bytes.
const MAX_MESSAGE: usize = 16 * 1024;

/// Most HTTPS connections at once (a few per browser), so a runaway client cannot exhaust the
/// operator's file descriptors.
const MAX_CONNECTIONS: usize = 64;

/// A TLS handshake must finish within this.
const HANDSHAKE_WAIT: Duration = Duration::from_secs(10);

const INDEX: &str = include_str!("page/index.html");
const SCRIPT: &str = include_str!("page/app.js");
const STYLE: &str = include_str!("page/style.css");

pub(super) struct Slot {
    config: OperatorConfig,
    running: tokio::sync::Mutex<Option<Running>>,
}

pub(super) struct Shared {
    devices: Vec<Slot>,
    pairing: Mutex<Pairing>,
    /// The host operator's clock: pairing times, and the time of its console's notices.
    clock: Clock,
    /// The host operator's events: pairing codes are shown in its console too.
    notices: broadcast::Sender<rove_console::Stamped>,
    connections: std::sync::atomic::AtomicU64,
    options: Options,
}

fn random() -> [u8; 16] {
    let mut bytes = [0u8; 16];
    // The OS's generator fails only on a broken system; a zero code is then still one-use.
    if let Err(e) = getrandom::fill(&mut bytes) {
        warn!(cause = %e, "no randomness from the OS");
    }
    bytes
}

impl Shared {
    fn pairing<T>(&self, f: impl FnOnce(&mut Pairing) -> T) -> T {
        f(&mut crate::runtime::lock(&self.pairing))
    }

    /// Logs the pairing code and shows it in the host's console.
    fn announce_code(&self) {
        let code = self.pairing(|p| p.code().to_string());
        info!(code = %code, valid_s = pairing::CODE_LIFETIME.as_secs(), "web: pair a browser with this code");
        let _ = self.notices.send(rove_console::Stamped {
            at: self.clock.now(),
            event: Event::Notice {
                text: format!("web: pairing code {code}"),
            },
        });
    }

    fn renew_code(&self) {
        let now = self.clock.now();
        self.pairing(|p| {
            p.renew(now, random());
        });
        self.announce_code();
    }
}

/// The browser console of one operator: [`WebConsole::bind`], then [`WebConsole::run`] until
/// its `stop` fires; it returns once every web device has released its vehicles and left.
pub struct WebConsole {
    shared: Arc<Shared>,
    listener: tokio::net::TcpListener,
    acceptor: tokio_rustls::TlsAcceptor,
}

impl std::fmt::Debug for WebConsole {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WebConsole").finish_non_exhaustive()
    }
}

impl WebConsole {
    /// Binds the HTTPS listener and loads or makes the certificate.
    ///
    /// # Errors
    /// The certificate cannot be loaded or made, or the address cannot be bound.
    pub async fn bind(
        web: &WebConfig,
        options: &Options,
        notices: broadcast::Sender<rove_console::Stamped>,
        clock: Clock,
    ) -> anyhow::Result<WebConsole> {
        let identity = tls::identity(web.certificate.as_ref(), web.listen)?;
        let listener = tokio::net::TcpListener::bind(web.listen)
            .await
            .map_err(|e| anyhow::anyhow!("[web] listen {}: {e}", web.listen))?;
        let shared = Shared {
            devices: (web.devices.iter())
                .map(|config| Slot {
                    config: config.clone(),
                    running: tokio::sync::Mutex::new(None),
                })
                .collect(),
            pairing: Mutex::new(Pairing::new(
                clock.now(),
                web.devices.len(),
                web.session,
                random(),
            )),
            clock,
            notices,
            connections: std::sync::atomic::AtomicU64::new(0),
            options: Options {
                config_path: options.config_path.clone(),
                ..Options::default()
            },
        };
        let devices: Vec<String> = (web.devices.iter())
            .map(|d| {
                format!(
                    "{} ({}, strength {})",
                    d.common.id, d.common.name, d.strength.0
                )
            })
            .collect();
        info!(
            listen = %listener.local_addr().unwrap_or(web.listen),
            certificate = %identity.origin,
            sha256 = %identity.fingerprint,
            devices = ?devices,
            session_s = web.session.as_secs(),
            "web console listening (https)"
        );
        let shared = Arc::new(shared);
        shared.announce_code();
        Ok(WebConsole {
            shared,
            listener,
            acceptor: tokio_rustls::TlsAcceptor::from(identity.config),
        })
    }

    /// Serves until `stop` completes, then stops every web device (each releases its vehicles
    /// and leaves) and returns.
    pub async fn run(self, stop: impl std::future::Future<Output = ()>) {
        let router = axum::Router::new()
            .route(
                "/",
                get(|| async { page(INDEX, "text/html; charset=utf-8") }),
            )
            .route(
                "/app.js",
                get(|| async { page(SCRIPT, "text/javascript; charset=utf-8") }),
            )
            .route(
                "/style.css",
                get(|| async { page(STYLE, "text/css; charset=utf-8") }),
            )
            .route("/pair", post(pair))
            .route("/ws", get(upgrade))
            .with_state(Arc::clone(&self.shared));
        let permits = Arc::new(tokio::sync::Semaphore::new(MAX_CONNECTIONS));
        // Once a second: a new pairing code when the old one is stale, and devices whose
        // browsers left are stopped.
        let mut housekeeping = tokio::time::interval(Duration::from_secs(1));
        tokio::pin!(stop);
        loop {
            tokio::select! {
                () = &mut stop => break,
                _ = housekeeping.tick() => {
                    let now = self.shared.clock.now();
                    if self.shared.pairing(|p| p.code_stale(now)) {
                        self.shared.renew_code();
                    }
                    reap(&self.shared).await;
                }
                accepted = self.listener.accept() => {
                    let (tcp, peer) = match accepted {
                        Ok(a) => a,
                        Err(e) => {
                            warn!(cause = %e, "web: accept failed");
                            tokio::time::sleep(Duration::from_millis(100)).await;
                            continue;
                        }
                    };
                    let Ok(permit) = Arc::clone(&permits).try_acquire_owned() else {
                        debug!(%peer, "web: too many connections, closing one");
                        continue;
                    };
                    let acceptor = self.acceptor.clone();
                    let router = router.clone();
                    tokio::spawn(async move {
                        let _permit = permit;
                        serve_connection(acceptor, router, tcp, peer).await;
                    });
                }
            }
        }
        for slot in &self.shared.devices {
            stop_device(slot).await;
        }
    }
}

async fn serve_connection(
    acceptor: tokio_rustls::TlsAcceptor,
    router: axum::Router,
    tcp: tokio::net::TcpStream,
    peer: std::net::SocketAddr,
) {
    let _ = tcp.set_nodelay(true);
    let tls = match tokio::time::timeout(HANDSHAKE_WAIT, acceptor.accept(tcp)).await {
        Ok(Ok(tls)) => tls,
        Ok(Err(e)) => {
            // Browsers close the first connection to a certificate they do not trust yet.
            debug!(%peer, cause = %e, "web: TLS handshake failed");
            return;
        }
        Err(_) => return,
    };
    let service = hyper_util::service::TowerToHyperService::new(router);
    let served = hyper::server::conn::http1::Builder::new()
        .serve_connection(hyper_util::rt::TokioIo::new(tls), service)
        .with_upgrades()
        .await;
    if let Err(e) = served {
        debug!(%peer, cause = %e, "web: connection ended");
    }
}

/// A page asset, never cached (the binary is the page's version), never framed.
fn page(body: &'static str, kind: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, kind),
            (header::CACHE_CONTROL, "no-store"),
            (header::X_FRAME_OPTIONS, "DENY"),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
            (
                header::CONTENT_SECURITY_POLICY,
                "default-src 'self'; connect-src 'self'; img-src 'self' data:; frame-ancestors 'none'",
            ),
        ],
        body,
    )
        .into_response()
}

fn json_reply(status: StatusCode, value: &serde_json::Value) -> Response {
    (
        status,
        [
            (header::CONTENT_TYPE, "application/json"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        value.to_string(),
    )
        .into_response()
}

/// `POST /pair` with `{"code":"123456"}`: a token and the device it speaks for.
async fn pair(State(shared): State<Arc<Shared>>, body: axum::body::Bytes) -> Response {
    let error = |status, text: &str, code: &str| {
        json_reply(status, &json!({ "error": text, "code": code }))
    };
    if body.len() > MAX_MESSAGE {
        return error(
            StatusCode::PAYLOAD_TOO_LARGE,
            "request too large",
            "too_long",
        );
    }
    let code = serde_json::from_slice::<serde_json::Value>(&body)
        .ok()
        .and_then(|v| v.get("code").and_then(|c| c.as_str()).map(str::to_string));
    let Some(code) = code else {
        return error(
            StatusCode::BAD_REQUEST,
            "expected {\"code\":\"123456\"}",
            "bad_json",
        );
    };
    let mut connected = Vec::new();
    for slot in &shared.devices {
        let running = slot.running.lock().await;
        connected.push(
            running
                .as_ref()
                .is_some_and(|r| r.connection.borrow().is_some()),
        );
    }
    let now = shared.clock.now();
    let paired = shared.pairing(|p| p.pair(now, &code, |d| connected[d], random()));
    match paired {
        Ok((token, device)) => {
            let config = &shared.devices[device].config;
            info!(device = config.common.id, name = %config.common.name, "web: a browser paired");
            shared.renew_code();
            json_reply(
                StatusCode::OK,
                &json!({
                    "token": token, "device": config.common.id, "name": config.common.name,
                }),
            )
        }
        Err(e) => {
            warn!(cause = %e, "web: pairing refused");
            let status = match e {
                pairing::PairError::WrongCode => StatusCode::FORBIDDEN,
                pairing::PairError::AllInUse => StatusCode::CONFLICT,
            };
            error(status, &e.to_string(), "pair_refused")
        }
    }
}

async fn upgrade(State(shared): State<Arc<Shared>>, ws: WebSocketUpgrade) -> Response {
    ws.max_message_size(MAX_MESSAGE)
        .max_frame_size(MAX_MESSAGE)
        .on_upgrade(move |socket| connection(shared, socket))
}

async fn send(socket: &mut WebSocket, value: &serde_json::Value) -> bool {
    socket
        .send(Message::Text(value.to_string().into()))
        .await
        .is_ok()
}

/// One browser connection: the token first, then lines out and frames and commands in.
async fn connection(shared: Arc<Shared>, mut socket: WebSocket) {
    let token = match tokio::time::timeout(AUTH_WAIT, socket.recv()).await {
        Ok(Some(Ok(Message::Text(text)))) => serde_json::from_str::<serde_json::Value>(&text)
            .ok()
            .and_then(|v| v.get("auth").and_then(|t| t.as_str()).map(str::to_string)),
        _ => None,
    };
    let checked = match token {
        Some(token) => shared
            .pairing(|p| p.check(shared.clock.now(), &token))
            .map_err(|e| (e.to_string(), "bad_token")),
        None => Err(("expected {\"auth\":TOKEN} first".to_string(), "bad_token")),
    };
    let device = match checked {
        Ok(d) => d,
        Err((why, code)) => {
            debug!(why, "web: a connection was refused");
            send(&mut socket, &json!({ "error": why, "code": code })).await;
            let _ = socket.send(Message::Close(None)).await;
            return;
        }
    };
    let slot = &shared.devices[device];
    let me = shared
        .connections
        .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let attached = {
        let mut running = slot.running.lock().await;
        if running.as_ref().is_none_or(|r| r.operator.is_finished()) {
            *running = Some(start_device(&slot.config, &shared.options));
        }
        let Some(r) = running.as_mut() else { return };
        // A newer connection speaks for the device: an older one (another tab) is closed.
        r.connection.send_replace(Some(me));
        r.idle_since = None;
        (
            r.input.clone(),
            Arc::clone(&r.wake),
            r.clock,
            r.hub.clone(),
            r.commands.clone(),
            r.connection.subscribe(),
        )
    };
    let (input, wake, clock, hub, commands, mut current) = attached;
    let id = slot.config.common.id;
    info!(device = id, connection = me, "web: browser connected");
    let ended = match hub.join().await {
        Joined::Lines(lines) => {
            let link = Link {
                input: &input,
                wake: &wake,
                clock,
                commands: &commands,
                id,
            };
            match serve_page(&mut socket, lines, &mut current, me, link).await {
                Some(why) => why,
                // Replaced by a newer connection, which speaks for the device now.
                None => return,
            }
        }
        Joined::Busy | Joined::Stopped => {
            let refusal = json!({"error": "the device is stopping", "code": "unavailable"});
            send(&mut socket, &refusal).await;
            "the device is stopping"
        }
    };
    info!(
        device = id,
        connection = me,
        why = ended,
        "web: browser disconnected"
    );
    input.with(|r| r.lost(&format!("browser: {ended}")));
    wake.notify_one();
    let mut running = slot.running.lock().await;
    if let Some(r) = running.as_mut()
        && *r.connection.borrow() == Some(me)
    {
        r.connection.send_replace(None);
        r.idle_since = Some(tokio::time::Instant::now());
    }
}

/// What a page's connection talks to.
struct Link<'a> {
    input: &'a WebInput,
    wake: &'a Notify,
    clock: Clock,
    commands: &'a mpsc::Sender<CommandRequest>,
    id: rove_core::msg::DeviceId,
}

/// Serves an authenticated page until it goes (why) or a newer connection replaces it (`None`).
async fn serve_page(
    socket: &mut WebSocket,
    mut lines: mpsc::Receiver<String>,
    current: &mut watch::Receiver<Option<u64>>,
    me: u64,
    link: Link<'_>,
) -> Option<&'static str> {
    let mut line_no = 0u64;
    loop {
        tokio::select! {
            line = lines.recv() => match line {
                Some(line) => {
                    if socket.send(Message::Text(line.into())).await.is_err() {
                        return Some("connection closed");
                    }
                }
                None => return Some("the device stopped"),
            },
            changed = current.changed() => {
                if changed.is_err() || *current.borrow() != Some(me) {
                    let why = "another browser tab took over this device";
                    send(socket, &json!({"error": why, "code": "replaced"})).await;
                    let _ = socket.send(Message::Close(None)).await;
                    // The newer connection speaks for the device now: no loss to tell.
                    return None;
                }
            }
            message = socket.recv() => {
                let text = match message {
                    Some(Ok(Message::Text(text))) => text,
                    Some(Ok(Message::Close(_)) | Err(_)) | None => {
                        return Some("connection closed");
                    }
                    Some(Ok(_)) => continue,
                };
                match page_message(&text) {
                    PageMessage::Frame(frame) => {
                        link.input.with(|r| r.frame(link.clock.now(), frame));
                        link.wake.notify_one();
                        continue;
                    }
                    PageMessage::Lost(why) => {
                        link.input.with(|r| r.lost(&format!("browser: {why}")));
                        link.wake.notify_one();
                        continue;
                    }
                    PageMessage::Command => {}
                }
                // A command (docs/api.md); messages are bounded by MAX_MESSAGE, far below the
                // API's line limit. `line` counts commands only, not frames.
                line_no += 1;
                let raw = Ok(text.as_bytes().to_vec());
                let source = Source::Web(link.id);
                let reply = answer(raw, line_no, link.commands, source).await;
                if socket.send(Message::Text(reply.to_json().into())).await.is_err() {
                    return Some("connection closed");
                }
            }
        }
    }
}
