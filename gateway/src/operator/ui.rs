//! What the operator loop tells its front ends (the terminal console, the local API, a
//! browser): events on a broadcast channel, only when something changed; button presses to
//! confirm go to the console.

use crate::runtime::{Clock, RateLimited};
use rove_console::model::InputStatus as UiInput;
use rove_console::{Event, Stamped};
use rove_core::adapter::InputAction;
use rove_core::session::{OperatorSession, Report};
use tracing::{info, warn};

/// The console's and the local API's view of the operator: events out, button presses to the
/// console (which asks for confirmation) when one runs.
pub(super) struct Ui {
    pub(super) tx: tokio::sync::broadcast::Sender<Stamped>,
    pub(super) clock: Clock,
    pub(super) actions: Option<tokio::sync::mpsc::Sender<InputAction>>,
    /// The last input and stream snapshots sent, so only changes go out.
    pub(super) shown_input: Option<UiInput>,
    pub(super) shown_streams: Option<rove_core::session::Streams>,
    /// When a message that was not believed was last logged and shown: a flood of them is
    /// told at most once per [`RateLimited::INTERVAL`].
    pub(super) untrusted_told: std::cell::Cell<Option<std::time::Instant>>,
}

impl Ui {
    pub(super) fn emit(&self, event: Event) {
        // No receiver (no console, no API client) is not an error.
        let _ = self.tx.send(Stamped {
            at: self.clock.now(),
            event,
        });
    }

    /// Whether anyone listens: the console and the API subscribe at start or never.
    pub(super) fn watched(&self) -> bool {
        self.tx.receiver_count() > 0
    }

    /// Sends the input's and the streams' state when they changed.
    pub(super) fn show(&mut self, session: &OperatorSession, link: &(Option<bool>, String)) {
        let streams = session.streams();
        if self.shown_streams.as_ref() != Some(&streams) {
            self.emit(Event::Driving {
                driving: streams.driving.clone(),
                holding: streams.holding.clone(),
                standby: streams.standby.clone(),
                paused: streams.paused.clone(),
            });
            self.shown_streams = Some(streams);
        }
        if !self.watched() {
            return;
        }
        let (movement, mode, live) = session.input();
        let input = UiInput {
            movement,
            mode,
            deadman: link.0,
            live,
            link: link.1.clone(),
        };
        if self.shown_input.as_ref() != Some(&input) {
            self.emit(Event::Input(input.clone()));
            self.shown_input = Some(input);
        }
    }

    /// Logs a session report and tells the console what it shows.
    pub(super) fn report(&self, report: Report) {
        if let Report::Untrusted(_) = report {
            let last = self.untrusted_told.get();
            if last.is_some_and(|t| t.elapsed() < RateLimited::INTERVAL) {
                return;
            }
            self.untrusted_told.set(Some(std::time::Instant::now()));
        }
        let vehicle = report.vehicle();
        if report.is_warning() {
            warn!(vehicle, "{report}");
        } else {
            info!(vehicle, "{report}");
        }
        let event = match report {
            Report::Selected { vehicle } => Event::Selected { vehicle },
            Report::RequestSent { vehicle, owner } => Event::RequestSent { vehicle, owner },
            Report::Prompt(prompt) => Event::RequestIncoming(prompt),
            Report::PromptClosed { vehicle, outcome } => Event::PromptClosed { vehicle, outcome },
            Report::RequestEnded { vehicle, outcome } => Event::RequestEnded { vehicle, outcome },
            Report::Untrusted(suspect) => Event::Notice {
                text: format!("not believed: {suspect}"),
            },
            _ => return,
        };
        self.emit(event);
    }
}
