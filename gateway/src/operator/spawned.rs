//! An operator loop on a task of its own, in a process whose role is another's: a web
//! console's device (`web/device.rs`) or a vehicle's ground station (`vehicle/stations.rs`).

use super::{Edges, Options, run};
use crate::config::OperatorConfig;
use std::time::Duration;
use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tracing::warn;

/// How long a stopping loop may take to finish its grants, release and leave before it is
/// aborted.
pub const STOP_BOUND: Duration = Duration::from_secs(5);

/// A running operator loop, and how to stop it.
#[derive(Debug)]
pub struct Spawned {
    id: rove_core::msg::DeviceId,
    what: &'static str,
    stop: Option<oneshot::Sender<()>>,
    task: JoinHandle<()>,
}

impl Spawned {
    /// Runs [`run`] for `config` on a task of its own until [`Spawned::signal`]; an error that
    /// ends it early is logged as `what` ("web device", "ground station's operator").
    pub fn start(
        config: OperatorConfig,
        options: Options,
        edges: Edges,
        what: &'static str,
    ) -> Spawned {
        let (stop_tx, stop_rx) = oneshot::channel::<()>();
        let id = config.common.id;
        let task = tokio::spawn(async move {
            let stop = async {
                let _ = stop_rx.await;
            };
            if let Err(e) = run(config, options, edges, stop).await {
                warn!(device = id, cause = %format!("{e:#}"), "{what} stopped");
            }
        });
        Spawned {
            id,
            what,
            stop: Some(stop_tx),
            task,
        }
    }

    /// Whether the loop ended.
    pub fn is_finished(&self) -> bool {
        self.task.is_finished()
    }

    /// Tells the loop to stop: it finishes its grants, releases its vehicles and leaves.
    pub fn signal(&mut self) {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
    }

    /// Waits for the loop to end after [`Spawned::signal`], at most `bound`; one that outlasts
    /// it is aborted.
    pub async fn wait(&mut self, bound: Duration) {
        if tokio::time::timeout(bound, &mut self.task).await.is_err() {
            warn!(
                device = self.id,
                "{} did not stop within {} s",
                self.what,
                bound.as_secs()
            );
            self.task.abort();
        }
    }

    /// [`Spawned::signal`], then [`Spawned::wait`].
    pub async fn stop(&mut self, bound: Duration) {
        self.signal();
        self.wait(bound).await;
    }
}
