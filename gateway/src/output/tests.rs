use super::worker::*;
use super::*;
use rove_core::msg::{Mode, MovementCommand};
use std::sync::{Arc, Mutex};

/// Records its calls; the first keep-alive fails (a link still connecting).
#[derive(Debug)]
struct Flaky(Arc<Mutex<Vec<&'static str>>>);

impl OutputAdapter for Flaky {
    fn describe(&self) -> String {
        "flaky".into()
    }
    fn apply(&mut self, _: MonoTime, _: &Setpoint) -> Result<(), LinkError> {
        self.0
            .lock()
            .map_err(|_| LinkError::fatal("poisoned"))?
            .push("apply");
        Ok(())
    }
    fn safe_state(&mut self, _: MonoTime) -> Result<(), LinkError> {
        self.0
            .lock()
            .map_err(|_| LinkError::fatal("poisoned"))?
            .push("safe");
        Ok(())
    }
    fn keepalive_period(&self) -> Option<Duration> {
        Some(Duration::from_secs(10))
    }
    fn keepalive(&mut self, _: MonoTime) -> Result<(), LinkError> {
        let mut calls = self.0.lock().map_err(|_| LinkError::fatal("poisoned"))?;
        calls.push("keepalive");
        if calls.len() == 1 {
            return Err(LinkError::transient("not connected (connecting)"));
        }
        Ok(())
    }
    fn health(&self) -> Health {
        Health::Ok
    }
}

/// Records the throttle of every apply (and `i16::MIN` for a safe state); every call waits
/// while the gate is shut, as a blocked device write would.
#[derive(Debug)]
struct Gated {
    calls: Arc<Mutex<Vec<i16>>>,
    gate: Arc<(Mutex<bool>, std::sync::Condvar)>,
}

impl Gated {
    fn pass(&self, throttle: i16) -> Result<(), LinkError> {
        let (shut, opened) = &*self.gate;
        let guard = shut.lock().map_err(|_| LinkError::fatal("poisoned"))?;
        let _open = opened
            .wait_while(guard, |shut| *shut)
            .map_err(|_| LinkError::fatal("poisoned"))?;
        self.calls
            .lock()
            .map_err(|_| LinkError::fatal("poisoned"))?
            .push(throttle);
        Ok(())
    }
}

impl OutputAdapter for Gated {
    fn describe(&self) -> String {
        "gated".into()
    }
    fn apply(&mut self, _: MonoTime, setpoint: &Setpoint) -> Result<(), LinkError> {
        self.pass(setpoint.movement.throttle)
    }
    fn safe_state(&mut self, _: MonoTime) -> Result<(), LinkError> {
        self.pass(i16::MIN)
    }
    fn health(&self) -> Health {
        Health::Ok
    }
}

/// An output thread over a [`Gated`] adapter: deadline 20 ms, max age 1 s.
fn gated_worker(
    clock: crate::runtime::Clock,
    calls: &Arc<Mutex<Vec<i16>>>,
    gate: &Arc<(Mutex<bool>, std::sync::Condvar)>,
) -> OutputWorker {
    let adapter = Gated {
        calls: Arc::clone(calls),
        gate: Arc::clone(gate),
    };
    let limits = WriteLimits {
        deadline: Duration::from_millis(20),
        max_age: Duration::from_secs(1),
    };
    OutputWorker::start_with(clock, limits, "gated", move |_| {
        Ok(ManagedOutput {
            config: OutputConfig::sim(),
            adapter: Some(Box::new(adapter)),
            hold_until: None,
            next_keepalive: None,
            last_error: None,
            last_status_error: None,
        })
    })
    .expect("worker")
}

fn throttle(t: i16) -> Setpoint {
    Setpoint {
        movement: MovementCommand {
            throttle: t,
            ..MovementCommand::CENTRED
        },
        mode: Mode::Manual,
    }
}

fn shut(gate: &(Mutex<bool>, std::sync::Condvar), value: bool) {
    *gate.0.lock().expect("gate") = value;
    gate.1.notify_all();
}

#[test]
fn a_blocked_device_call_never_blocks_the_loop_and_only_the_newest_command_follows() {
    let calls = Arc::new(Mutex::new(Vec::new()));
    let gate = Arc::new((Mutex::new(false), std::sync::Condvar::new()));
    // A clock already 10 s old, so that a command decided at 0 is stale.
    let clock = crate::runtime::Clock::since(std::time::Instant::now() - Duration::from_secs(10));
    let worker = gated_worker(clock, &calls, &gate);
    let recorded = || calls.lock().expect("calls").clone();
    worker.apply(clock.now(), throttle(1));
    rove_testkit::eventually("the first apply", || match recorded()[..] {
        [1] => Ok(()),
        ref other => Err(format!("{other:?}")),
    });
    assert_eq!(worker.report().hung, None);

    // The device blocks: the call is reported hung once past the deadline, and handing
    // over commands meanwhile does not wait for it.
    shut(&gate, true);
    worker.apply(clock.now(), throttle(2));
    rove_testkit::eventually("the call reported hung", || {
        worker.report().hung.ok_or("not hung yet")
    });
    for t in 3..=50 {
        worker.apply(clock.now(), throttle(t));
    }
    shut(&gate, false);
    // Only the newest of the commands that queued up is written.
    rove_testkit::eventually("the newest command", || match recorded()[..] {
        [1, 2, 50] => Ok(()),
        ref other => Err(format!("{other:?}")),
    });
    rove_testkit::eventually("hung no more", || match worker.report().hung {
        None => Ok(()),
        Some(h) => Err(format!("{h:?}")),
    });

    // A command older than max_age when the device is free is not written; a safe state
    // always is.
    worker.apply(MonoTime::ZERO, throttle(99));
    rove_testkit::eventually("99 skipped", || match worker.report().stale {
        1 => Ok(()),
        n => Err(format!("{n} stale")),
    });
    worker.safe_state();
    rove_testkit::eventually("the safe state", || match recorded()[..] {
        [1, 2, 50, i16::MIN] => Ok(()),
        ref other => Err(format!("{other:?}")),
    });
    shut(&gate, true);
    worker.apply(clock.now(), throttle(7));
    rove_testkit::eventually("7 taken", || worker.report().hung.ok_or("not taken yet"));
    worker.apply(MonoTime::ZERO, throttle(98));
    shut(&gate, false);
    rove_testkit::eventually("98 skipped", || match worker.report().stale {
        2 => Ok(()),
        n => Err(format!("{n} stale")),
    });
    worker.apply(clock.now(), throttle(8));
    rove_testkit::eventually("the fresh ones", || match recorded()[..] {
        [1, 2, 50, i16::MIN, 7, 8] => Ok(()),
        ref other => Err(format!("{other:?}")),
    });
    assert!(
        worker.stop(Duration::from_secs(10)),
        "a free device stops at once"
    );
    assert_eq!(
        recorded().last(),
        Some(&i16::MIN),
        "stopping writes the safe state"
    );
}

#[test]
fn stopping_gives_up_on_a_device_that_does_not_return() {
    let gate = Arc::new((Mutex::new(true), std::sync::Condvar::new()));
    let clock = crate::runtime::Clock::start();
    let worker = gated_worker(clock, &Arc::new(Mutex::new(Vec::new())), &gate);
    worker.apply(clock.now(), throttle(5));
    rove_testkit::eventually("hung", || worker.report().hung.ok_or("not hung yet"));
    assert!(!worker.stop(Duration::from_millis(50)));
    shut(&gate, false);
}

/// Regression (against ArduPilot SITL): a hold that ends in the same loop turn as the first command must not put the
/// adapter, already driving, in its safe state.
#[test]
fn r20_a_successful_apply_ends_the_hold() {
    let calls = Arc::new(Mutex::new(Vec::new()));
    let mut out = ManagedOutput {
        config: OutputConfig::sim(),
        adapter: Some(Box::new(Flaky(Arc::clone(&calls)))),
        hold_until: None,
        next_keepalive: None,
        last_error: None,
        last_status_error: None,
    };
    let t0 = MonoTime::ZERO;
    out.tick(t0); // the keep-alive fails: held safe for RETRY
    assert_eq!(out.next_deadline(), Some(t0 + RETRY));
    let sp = Setpoint {
        movement: MovementCommand::CENTRED,
        mode: Mode::Manual,
    };
    out.apply(t0 + RETRY / 2, &sp);
    // The first command arrives as the hold ends, before the loop's tick for its end.
    let end = t0 + RETRY;
    out.apply(end, &sp);
    out.tick(end);
    let calls = calls.lock().map(|c| c.clone()).unwrap_or_default();
    assert_eq!(
        calls,
        ["keepalive", "apply"],
        "held while holding, then driving with no safe state after it"
    );
    assert_eq!(out.health(), Health::Ok);
}
