//! [`run_terminal`]: the interactive console on the controlling terminal.
//!
//! It owns the terminal (raw mode, alternate screen; restored on return, on drop and on panic),
//! reads keys on a thread (crossterm's reads block), and exchanges [`Stamped`] events and
//! [`CommandRequest`]s with the operator over the same channels as the API server.

use crate::command::{Command, CommandRequest, Source};
use crate::keys::{on_action, on_key};
use crate::model::{ConsoleState, Event, Stamped};
use crate::view::render;
use rove_core::MonoTime;
use rove_core::adapter::InputAction;
use std::io;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;
use tokio::sync::{broadcast, mpsc, oneshot};

/// Redraw period without events: the consent countdown and "last seen" ages move by
/// themselves; 4 Hz shows seconds smoothly at negligible cost.
pub const REDRAW_PERIOD: Duration = Duration::from_millis(250);

/// How long the key thread blocks in one poll before checking whether to stop: bounds how
/// long it outlives the console.
const KEY_POLL: Duration = Duration::from_millis(100);

/// Runs the console until the person quits (`q`, Ctrl-C) or the operator closes `events`.
///
/// - `state`: the initial state (usually `ConsoleState::new(identity, offline_after)`);
///   subscribe `events` before the operator emits anything so nothing is missed.
/// - `clock`: the operator's clock, read for key times and countdowns.
/// - `commands`: where keys' and buttons' commands go ([`Source::Console`]); a refusal is shown
///   in the log.
/// - `actions`: the input device's buttons, forwarded by the operator instead of handling them
///   itself while the console runs.
///
/// Raw mode turns Ctrl-C into a key, not SIGINT: the caller must treat the return as "stop the
/// operator" (release and exit), as it would a signal. Tracing output to stderr would draw over
/// the screen; send it to a file (or nowhere) while the console runs.
///
/// # Errors
/// The terminal cannot be set up, drawn or read.
pub async fn run_terminal(
    mut state: ConsoleState,
    clock: impl Fn() -> MonoTime,
    mut events: broadcast::Receiver<Stamped>,
    commands: mpsc::Sender<CommandRequest>,
    mut actions: mpsc::Receiver<InputAction>,
) -> io::Result<()> {
    let mut terminal = TerminalGuard(ratatui::try_init()?);
    let (key_tx, mut keys) = mpsc::channel(64);
    let stop = Arc::new(AtomicBool::new(false));
    let reader = {
        let stop = Arc::clone(&stop);
        std::thread::Builder::new()
            .name("console-keys".into())
            .spawn(move || read_keys(&key_tx, &stop))?
    };
    let (note_tx, mut notes) = mpsc::channel::<String>(16);
    let mut redraw = tokio::time::interval(REDRAW_PERIOD);
    let mut buttons_open = true;
    let result = loop {
        let now = clock();
        if let Err(e) = terminal.0.draw(|f| render(f, &state, now)) {
            break Err(e);
        }
        let command = tokio::select! {
            event = events.recv() => match event {
                Ok(s) => {
                    state.apply(s.at, s.event);
                    None
                }
                Err(broadcast::error::RecvError::Lagged(n)) => {
                    let text = format!("console fell behind: {n} events missed");
                    state.apply(clock(), Event::Notice { text });
                    None
                }
                Err(broadcast::error::RecvError::Closed) => break Ok(()),
            },
            key = keys.recv() => match key {
                Some(Ok(crossterm::event::Event::Key(key))) => on_key(&mut state, key, clock()),
                Some(Ok(_)) => None, // resize, mouse, focus: the next draw handles it
                Some(Err(e)) => break Err(e),
                None => break Err(io::Error::other("the key reader stopped")),
            },
            action = actions.recv(), if buttons_open => match action {
                Some(action) => on_action(&mut state, action, clock()),
                None => {
                    buttons_open = false;
                    None
                }
            },
            Some(text) = notes.recv() => {
                state.apply(clock(), Event::Notice { text });
                None
            },
            _ = redraw.tick() => {
                state.apply(clock(), Event::Tick);
                None
            },
        };
        if let Some(command) = command
            && !send(command, &commands, &note_tx).await
        {
            break Ok(()); // the operator is gone
        }
        if state.quit {
            break Ok(());
        }
    };
    stop.store(true, Ordering::Relaxed);
    drop(keys);
    drop(terminal);
    // The thread notices `stop` within one KEY_POLL; joining here would block the runtime.
    drop(reader);
    result
}

/// Sends `command`; a refusal comes back later as a note for the log. False if the operator
/// no longer takes commands.
async fn send(
    command: Command,
    commands: &mpsc::Sender<CommandRequest>,
    notes: &mpsc::Sender<String>,
) -> bool {
    let (reply, answer) = oneshot::channel();
    let request = CommandRequest {
        command,
        source: Source::Console,
        reply,
    };
    // Waits if the operator's queue is full: a release must never be dropped.
    if commands.send(request).await.is_err() {
        return false;
    }
    let notes = notes.clone();
    tokio::spawn(async move {
        let text = match answer.await {
            Ok(Ok(())) => return,
            Ok(Err(why)) => format!("{} refused: {why}", command.name()),
            Err(_) => format!("{}: no answer from the operator", command.name()),
        };
        let _ = notes.send(text).await;
    });
    true
}

fn read_keys(tx: &mpsc::Sender<io::Result<crossterm::event::Event>>, stop: &AtomicBool) {
    while !stop.load(Ordering::Relaxed) {
        match crossterm::event::poll(KEY_POLL) {
            Ok(false) => {}
            Ok(true) => {
                let event = crossterm::event::read();
                let failed = event.is_err();
                if tx.blocking_send(event).is_err() || failed {
                    return;
                }
            }
            Err(e) => {
                let _ = tx.blocking_send(Err(e));
                return;
            }
        }
    }
}

/// Restores the terminal however the console ends (return, `?`, cancellation).
struct TerminalGuard(ratatui::DefaultTerminal);

impl Drop for TerminalGuard {
    fn drop(&mut self) {
        let _ = ratatui::try_restore();
    }
}
