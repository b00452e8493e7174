//! Host assembly: what `rove vehicle` and `rove operator` put around their role's loop on this
//! machine — the clock, the stop signal, systemd's notifier, the operator's input device,
//! terminal console, local API socket and browser console. `main.rs` calls these; the roles
//! ([`crate::vehicle`], [`crate::operator`]) take what they are given and know none of it.

use crate::config::{OperatorConfig, VehicleConfig};
use crate::operator::{self, Edges};
use crate::runtime::{Clock, shutdown_signal};
use crate::sdnotify::Notifier;
use crate::vehicle;
use std::sync::Arc;
use tracing::{info, warn};

/// `rove vehicle`: the role on a fresh clock until SIGTERM or SIGINT.
///
/// # Errors
/// The role's (see [`vehicle::run`]), or a signal handler cannot be installed.
pub async fn vehicle(config: VehicleConfig, options: vehicle::Options) -> anyhow::Result<()> {
    vehicle::run(config, options, Clock::start(), shutdown_signal()?).await
}

/// `rove operator`: the role with this machine's front ends — the input device of `[input]`,
/// the local API (`[console] api_socket`), the browser console (`[web]`, whose devices are
/// operators of their own) and, with `options.console`, the terminal console, whose closing
/// stops the operator like `shutdown` does.
///
/// # Errors
/// The input cannot be opened, the API socket or the web console cannot be bound, or the
/// role's (see [`operator::run`]).
pub async fn operator(
    config: OperatorConfig,
    options: operator::Options,
    shutdown: impl std::future::Future<Output = ()>,
) -> anyhow::Result<()> {
    let wake = Arc::new(tokio::sync::Notify::new());
    let sticks = operator::open_sticks(&config, &wake)?;
    let (mut edges, commands) = Edges::new(sticks, wake, Notifier::from_env());
    let clock = edges.clock;
    let mirror = operator::console_state(&config);
    if let Some(path) = &config.api_socket {
        let socket = rove_console::ApiSocket::bind(path)
            .map_err(|e| anyhow::anyhow!("local API socket: {e}"))?;
        info!(path = %path.display(), "local API listening");
        let hub = rove_console::Hub::start(mirror.clone(), edges.events.subscribe());
        let serve = socket.serve(hub, commands.clone());
        tokio::spawn(async move {
            if let Err(e) = serve.await {
                warn!(cause = %e, "local API stopped");
            }
        });
    }
    // The browser console: its devices are operators of their own, stopped after this one.
    let (web_stop, web_stopped) = tokio::sync::oneshot::channel::<()>();
    let web = match &config.web {
        Some(web) => {
            let console =
                crate::web::WebConsole::bind(web, &options, edges.events.clone(), clock).await?;
            Some(tokio::spawn(console.run(async {
                let _ = web_stopped.await;
            })))
        }
        None => None,
    };
    let terminal = options.console.then(|| {
        let (confirm, presses) = tokio::sync::mpsc::channel(64);
        edges.confirm = Some(confirm);
        let events = edges.events.subscribe();
        rove_console::run_terminal(mirror, move || clock.now(), events, commands, presses)
    });
    let stop = async move {
        match terminal {
            None => shutdown.await,
            Some(terminal) => tokio::select! {
                _ = shutdown => {}
                ended = terminal => {
                    if let Err(e) = ended {
                        warn!(cause = %e, "console failed");
                    }
                    info!("console closed: stopping");
                }
            },
        }
    };
    let result = operator::run(config, options, edges, stop).await;
    if let Some(web) = web {
        let _ = web_stop.send(());
        if let Err(e) = web.await {
            warn!(cause = %e, "web console failed");
        }
    }
    result
}
