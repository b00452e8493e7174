//! The bench's hands: the operators and the vehicle as it drives them, a seeded generator, and
//! the network faults (nftables loss and cuts, the far namespace on a veth pair).

use super::contract::{Fault, Logged};
use super::{LADDER, VEHICLE};
use crate::harness::{Rig, wall_us};
use std::collections::BTreeMap;
use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

/// A small deterministic generator (xorshift64*): a seed replays a run's fault sequence.
#[derive(Debug)]
pub(super) struct Rng(pub(super) u64);

impl Rng {
    pub(super) fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// Uniform in `0..n` (`n` > 0).
    pub(super) fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }

    /// Uniform in `[lo, hi)`.
    pub(super) fn between(&mut self, lo: Duration, hi: Duration) -> Duration {
        let span = (hi - lo).as_micros().max(1) as u64;
        lo + Duration::from_micros(self.next() % span)
    }
}

/// The operators and the vehicle as the bench drives them.
pub(super) struct Fleet {
    pub(super) rig: Rig,
    pub(super) record: std::path::PathBuf,
    pub(super) vehicle: usize,
    /// id → its process in the rig while it runs.
    pub(super) running: BTreeMap<i64, usize>,
    /// id → when it is to be continued, while stopped.
    pub(super) stopped: BTreeMap<i64, Instant>,
    pub(super) log: Vec<Logged>,
    pub(super) failsafe_ms: Vec<f64>,
}

impl Fleet {
    /// Logs `fault`, begun at `at` (wall µs) and done now.
    pub(super) fn note(&mut self, at: u64, fault: Fault) {
        let done = wall_us();
        self.log.push(Logged { at, done, fault });
    }

    pub(super) fn start(&mut self, id: i64) {
        let at = wall_us();
        let (level, class) = LADDER[(id - 11) as usize];
        let proc = (self.rig).operator(id, level, class, &[VEHICLE], 1000 + id as i16, "", &[]);
        self.running.insert(id, proc);
        self.note(at, Fault::Start { id });
    }

    /// Sends `signal` to operator `id` and logs `fault`.
    pub(super) fn signal(&mut self, id: i64, signal: &str, fault: Fault) {
        let at = wall_us();
        if let Some(&proc) = self.running.get(&id) {
            self.rig.procs[proc].signal(signal);
        }
        self.note(at, fault);
    }

    pub(super) fn cont_due(&mut self, now: Instant) {
        let due: Vec<i64> = (self.stopped.iter())
            .filter(|(_, at)| **at <= now)
            .map(|(id, _)| *id)
            .collect();
        for id in due {
            self.stopped.remove(&id);
            self.signal(id, "-CONT", Fault::Cont { id });
        }
    }

    pub(super) fn restart_vehicle(&mut self, graceful: bool) -> anyhow::Result<()> {
        let at = wall_us();
        let proc = &mut self.rig.procs[self.vehicle];
        if graceful {
            proc.terminate();
            if proc.wait_exit(Duration::from_secs(5)).is_none() {
                proc.crash();
            }
        } else {
            proc.crash();
        }
        // As systemd's ExecStopPost= would, then Restart=.
        let config = self.rig.dir.join(format!("vehicle-{VEHICLE}.toml"));
        let started = Instant::now();
        let status = (self.rig)
            .command(&["failsafe", "-c", config.to_str().unwrap_or_default()])
            .output()?;
        anyhow::ensure!(
            status.status.success(),
            "rove failsafe: {}",
            String::from_utf8_lossy(&status.stderr)
        );
        self.failsafe_ms
            .push(started.elapsed().as_secs_f64() * 1000.0);
        let args = [
            "vehicle",
            "-c",
            config.to_str().unwrap_or_default(),
            "--record",
            self.record.to_str().unwrap_or_default(),
        ];
        self.vehicle = self.rig.spawn(&format!("vehicle-{VEHICLE}"), &args);
        self.note(at, Fault::VehicleRestart { graceful });
        Ok(())
    }

    /// Every operator running and continued.
    pub(super) fn heal(&mut self, ids: &[i64]) {
        self.cont_due(Instant::now() + Duration::from_secs(3600));
        for &id in ids {
            if !self.running.contains_key(&id) {
                self.start(id);
            }
        }
    }
}

/// The vehicle's end of the veth pair to the far namespace.
pub(super) const VETH_NEAR: &str = "10.77.0.1";
/// The far operator's end.
pub(super) const VETH_FAR: &str = "10.77.0.2";

/// A second namespace joined to `near`'s by a veth pair (`VETH_NEAR` there, `VETH_FAR` here),
/// multicast routed over it: a host of its own on a link the bench can cut.
pub(super) fn far_namespace(rove: &Path, near: &Rig) -> anyhow::Result<Rig> {
    let far = Rig::new(rove, "bench-chaos-far")?;
    let (near_addr, far_addr) = (format!("{VETH_NEAR}/24"), format!("{VETH_FAR}/24"));
    crate::harness::veth(near, &far, &near_addr, &far_addr, true)?;
    Ok(far)
}

/// nftables in the rig's namespace: drops `pct` % of UDP packets (0 removes the rule).
pub(super) fn set_loss(rig: &Rig, pct: u8) -> anyhow::Result<()> {
    let rule = format!("meta l4proto udp numgen random mod 100 < {pct} drop");
    nft(rig, (pct > 0).then_some(&rule), &["input"])
}

/// The far operator's veth cut (both ways, silently: nothing is refused) or restored.
pub(super) fn set_cut(rig: &Rig, cut: bool) -> anyhow::Result<()> {
    nft(
        rig,
        cut.then_some("meta l4proto udp drop"),
        &["input", "output"],
    )
}

/// Replaces rove's nftables table in `rig`'s namespace with one holding `rule` in a filter
/// chain on each of `hooks`; `None` removes the table.
pub(super) fn nft(rig: &Rig, rule: Option<&str>, hooks: &[&str]) -> anyhow::Result<()> {
    let mut script = "table inet rove_chaos\ndelete table inet rove_chaos\n".to_string();
    if let Some(rule) = rule {
        script.push_str("table inet rove_chaos {\n");
        for hook in hooks {
            script.push_str(&format!(
                "chain {hook} {{ type filter hook {hook} priority 0; {rule}; }}\n"
            ));
        }
        script.push_str("}\n");
    }
    let path = rig.write("chaos.nft", &script);
    let out = Command::new("ip")
        .args(["netns", "exec", &rig.ns, "nft", "-f"])
        .arg(&path)
        .output()
        .map_err(|e| anyhow::anyhow!("nft (Debian: apt-get install nftables): {e}"))?;
    anyhow::ensure!(
        out.status.success(),
        "nft: {}",
        String::from_utf8_lossy(&out.stderr).trim()
    );
    Ok(())
}
