//! Two sites on one machine (`rove bridge`, docs/remote.md): the vehicles' site ("lab") and a
//! remote operators' site ("home"), each a rig (a network namespace with its own DDS network on
//! its loopback), joined by a veth pair that carries nothing but the bridges' link (no
//! multicast route over it). For the sites tests and `rove bench handover --remote`.

use crate::harness::{self, Rig};
use std::path::{Path, PathBuf};

/// The lab's end of the veth pair, where its bridge listens.
pub const LAB_ADDRESS: &str = "10.78.0.1";
/// Home's end.
pub const HOME_ADDRESS: &str = "10.78.0.2";

/// Joins `lab` and `home` by a veth pair (no multicast over it); returns the lab's interface.
///
/// # Errors
/// iproute2 refuses a step.
pub fn join(lab: &Rig, home: &Rig) -> anyhow::Result<String> {
    let near = format!("{LAB_ADDRESS}/24");
    let far = format!("{HOME_ADDRESS}/24");
    Ok(harness::veth(lab, home, &near, &far, false)?.0)
}

/// A fleet in `dir` (`rove keys`, run from `rove`) with a site certificate for the lab (naming its address, which connecting
/// bridges check) and for home; returns the fleet's directory.
///
/// # Errors
/// The keys cannot be made.
pub fn fleet(rove: &Path, dir: &Path) -> anyhow::Result<PathBuf> {
    let shown = dir.display().to_string();
    harness::keys(rove, &["init", "--dir", &shown, "--fleet", "rove sites"])?;
    harness::keys(
        rove,
        &[
            "site",
            "--dir",
            &shown,
            "--name",
            "lab",
            "--host",
            LAB_ADDRESS,
        ],
    )?;
    harness::keys(rove, &["site", "--dir", &shown, "--name", "home"])?;
    Ok(dir.to_path_buf())
}

/// How a bridge meets the other site.
#[derive(Debug, Clone, Copy)]
pub enum Meet<'a> {
    /// It listens there (a Zenoh router).
    Listen(&'a str),
    /// It connects there.
    Connect(&'a str),
}

/// A `[[zenoh.site]]` entry.
pub fn peer(name: &str, ids: &[i64], offer: &[i64]) -> String {
    let list = |v: &[i64]| v.iter().map(i64::to_string).collect::<Vec<_>>().join(", ");
    format!(
        "[[zenoh.site]]\nname = \"{name}\"\nids = [{}]\noffer = [{}]\n",
        list(ids),
        list(offer)
    )
}

/// Starts a bridge in `rig` calling itself `name`, meeting as `meet` with the certificate in
/// `site_dir` (a `rove keys site` directory) and `peers` (its `[[zenoh.site]]` entries);
/// returns its process index.
pub fn bridge(rig: &mut Rig, name: &str, meet: Meet, site_dir: &Path, peers: &str) -> usize {
    let endpoint = match meet {
        Meet::Listen(address) => format!("listen = [\"tls/{address}:7447\"]"),
        Meet::Connect(address) => format!("connect = [\"tls/{address}:7447\"]"),
    };
    let toml = format!(
        "[site]\nname = \"{name}\"\n[zenoh]\n{endpoint}\nca = \"{}\"\ncertificate = \"{}\"\n\
         key = \"{}\"\n{peers}",
        site_dir.join("ca.cert.pem").display(),
        site_dir.join("cert.pem").display(),
        site_dir.join("key.pem").display()
    );
    let n = rig.procs.len();
    let config = rig.write(&format!("bridge-{name}-{n}.toml"), &toml);
    let config = config.to_string_lossy().into_owned();
    rig.spawn(&format!("bridge-{name}"), &["bridge", "-c", &config])
}

/// Waits (up to `patience`) until the bridge logging to `log` has another site up.
///
/// # Errors
/// It has none up by then.
pub fn wait_up(log: &Path, patience: std::time::Duration) -> anyhow::Result<()> {
    let deadline = std::time::Instant::now() + patience;
    loop {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        if text.contains("site up") {
            return Ok(());
        }
        anyhow::ensure!(
            std::time::Instant::now() < deadline,
            "{}: no site up after {patience:?}",
            log.display()
        );
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

/// How the link is cut.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Cut {
    /// The lab's veth end down (both ends see the carrier go).
    Down,
    /// Every packet on the lab's veth end dropped, both ways, silently (nftables).
    Drop,
}

/// Cuts (`on`) or restores the link at the lab's interface `veth`.
///
/// # Errors
/// iproute2 or nft refuses.
pub fn cut(lab: &Rig, veth: &str, how: Cut, on: bool) -> anyhow::Result<()> {
    let script = match (how, on) {
        (Cut::Down, true) => format!("ip link set {veth} down"),
        (Cut::Down, false) => format!("ip link set {veth} up"),
        (Cut::Drop, true) => format!(
            "nft add table inet rove_sites && \
             nft add chain inet rove_sites in '{{ type filter hook input priority 0; }}' && \
             nft add chain inet rove_sites out '{{ type filter hook output priority 0; }}' && \
             nft add rule inet rove_sites in iifname {veth} drop && \
             nft add rule inet rove_sites out oifname {veth} drop"
        ),
        (Cut::Drop, false) => "nft delete table inet rove_sites".to_string(),
    };
    let out = std::process::Command::new("ip")
        .args(["netns", "exec", &lab.ns, "sh", "-c", &script])
        .output()?;
    anyhow::ensure!(
        out.status.success(),
        "{script}: {}",
        String::from_utf8_lossy(&out.stderr).trim()
    );
    Ok(())
}
