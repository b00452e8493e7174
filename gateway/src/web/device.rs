//! A web device: one browser's operator, with the browser's sticks as its input
//! ([`WebInput`]), started when its browser pairs and stopped when it has been gone a while.

use super::{LINGER, SILENCE, Shared, Slot};
use crate::config::OperatorConfig;
use crate::operator::{self, Edges, Options, STOP_BOUND, Spawned, Sticks};
use crate::runtime::Clock;
use rove_console::{CommandRequest, Hub};
use rove_core::adapter::{InputEvent, InputSource};
use rove_core::error::LinkError;
use rove_core::remote::{RemoteInput, RemoteLink};
use rove_core::time::MonoTime;
use std::sync::{Arc, Mutex};
use tokio::sync::{Notify, mpsc, watch};
use tracing::info;

/// Sticks from a browser: the operator loop's input source for a web device.
#[derive(Debug, Clone)]
pub struct WebInput(pub(super) Arc<Mutex<RemoteInput>>);

impl WebInput {
    pub(super) fn with<T>(&self, f: impl FnOnce(&mut RemoteInput) -> T) -> T {
        // Every RemoteInput method leaves it consistent: a poisoned lock is used as it is.
        f(&mut crate::runtime::lock(&self.0))
    }

    /// Whether the deadman is held, and the link in words, for the console.
    pub fn status(&self) -> (Option<bool>, String) {
        self.with(|r| {
            let text = match r.link() {
                RemoteLink::Live => "live".to_string(),
                RemoteLink::AwaitingCentre => {
                    "put a thumb on a stick (or hold the gamepad's shoulder button), sticks \
                     centred, to drive"
                        .to_string()
                }
                RemoteLink::Lost(why) => why.clone(),
            };
            (Some(r.deadman()), text)
        })
    }
}

impl Sticks for WebInput {
    fn link(&self) -> (Option<bool>, String) {
        self.status()
    }
}

impl InputSource for WebInput {
    fn describe(&self) -> String {
        "a browser (touch sticks or gamepad) over [web]".into()
    }

    fn poll(&mut self, now: MonoTime) -> Result<Option<InputEvent>, LinkError> {
        Ok(self.with(|r| {
            r.tick(now);
            r.pop()
        }))
    }

    fn next_deadline(&self) -> Option<MonoTime> {
        self.with(|r| r.next_deadline())
    }
}

/// A running web device: its operator loop and what its browser connection talks to.
pub(super) struct Running {
    pub(super) input: WebInput,
    pub(super) wake: Arc<Notify>,
    pub(super) clock: Clock,
    pub(super) hub: Hub,
    pub(super) commands: mpsc::Sender<CommandRequest>,
    /// Its operator loop.
    pub(super) operator: Spawned,
    /// The connection that speaks for the device now (a number per connection), if any.
    pub(super) connection: watch::Sender<Option<u64>>,
    /// When its last connection closed.
    pub(super) idle_since: Option<tokio::time::Instant>,
}

/// Starts a web device's operator loop.
pub(super) fn start_device(config: &OperatorConfig, options: &Options) -> Running {
    let input = WebInput(Arc::new(Mutex::new(RemoteInput::new(SILENCE))));
    let wake = Arc::new(Notify::new());
    // systemd hears from the host's operator only: a web device starting or stopping is not
    // the service's.
    let sticks: Box<dyn Sticks> = Box::new(input.clone());
    let (edges, commands_tx) = Edges::new(
        Some(sticks),
        Arc::clone(&wake),
        crate::sdnotify::Notifier::disabled(),
    );
    let clock = edges.clock;
    let hub = Hub::start(operator::console_state(config), edges.events.subscribe());
    let id = config.common.id;
    info!(device = id, "web: starting the device's participant");
    let operator = Spawned::start(config.clone(), options.clone(), edges, "web device");
    Running {
        input,
        wake,
        clock,
        hub,
        commands: commands_tx,
        operator,
        connection: watch::Sender::new(None),
        idle_since: None,
    }
}

/// Stops the devices whose browsers left more than [`LINGER`] ago.
pub(super) async fn reap(shared: &Shared) {
    for slot in &shared.devices {
        let idle = {
            let running = slot.running.lock().await;
            running
                .as_ref()
                .and_then(|r| r.idle_since)
                .is_some_and(|t| t.elapsed() >= LINGER)
        };
        if idle {
            info!(
                device = slot.config.common.id,
                "web: no browser for a while, the device leaves"
            );
            stop_device(slot).await;
        }
    }
}

/// Stops a device's loop (it releases its vehicles and leaves) and waits for it, bounded.
pub(super) async fn stop_device(slot: &Slot) {
    let Some(mut running) = slot.running.lock().await.take() else {
        return;
    };
    running.operator.stop(STOP_BOUND).await;
}
