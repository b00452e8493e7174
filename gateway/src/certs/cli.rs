//! `rove keys …`: the command line of a fleet's keys (the functions are in [`super`]).

use crate::certs;
use clap::Subcommand;

#[derive(Debug, Subcommand)]
/// `rove keys` subcommands.
pub enum KeysCommand {
    /// Create a fleet: its CA (identity and permissions) and its signed governance.
    Init {
        /// The fleet's directory (created).
        #[arg(long)]
        dir: std::path::PathBuf,
        /// The fleet's name (the certificates' organisation).
        #[arg(long, default_value = "rove fleet")]
        fleet: String,
        /// The DDS domain the fleet runs in.
        #[arg(long, default_value_t = 0)]
        domain: u16,
    },
    /// Issue a device's certificate (subject CN=rove-ID), key and signed permissions in DIR/ID/.
    Add {
        /// The fleet's directory.
        #[arg(long)]
        dir: std::path::PathBuf,
        /// The device id (vehicle or operator).
        #[arg(long)]
        id: i64,
        /// Days the certificate is valid (`rove doctor` warns 30 days before the end).
        #[arg(long, default_value_t = certs::Lifetime::DEVICE.days)]
        days: u32,
        /// Re-issue an existing device: a new key and certificate (copy the directory to the
        /// device again).
        #[arg(long)]
        renew: bool,
        /// Test hook, hidden from --help: the validity starts this many days from now
        /// (negative: in the past).
        #[arg(long, hide = true, default_value_t = 0, allow_negative_numbers = true)]
        starts_in_days: i64,
    },
    /// On the device: make its private key and a certificate request in DIR (the directory
    /// `[security] dir` names), for `rove keys sign` at the fleet CA. The key never leaves DIR.
    Request {
        /// The device's security directory (created, mode 0700).
        #[arg(long)]
        dir: std::path::PathBuf,
        /// The device id (vehicle or operator).
        #[arg(long)]
        id: i64,
    },
    /// At the fleet CA: sign a device's request (`rove keys request`): its certificate and
    /// permissions in DIR/ID/, with the CA, governance and revocation list, to copy to the
    /// device beside its key.
    Sign {
        /// The fleet's directory.
        #[arg(long)]
        dir: std::path::PathBuf,
        /// The request file (request.csr.pem from the device).
        #[arg(long)]
        request: std::path::PathBuf,
        /// The device id, as confirmed with the device (the request must name it).
        #[arg(long)]
        id: i64,
        /// Days the certificate is valid.
        #[arg(long, default_value_t = certs::Lifetime::DEVICE.days)]
        days: u32,
        /// Re-issue an existing device (for its new request).
        #[arg(long)]
        renew: bool,
    },
    /// Revoke a device's certificate: the fleet's revocation list (crl.pem) names it, and every
    /// device directory in the fleet gets the new list (copy it to the devices, as the
    /// governance; running devices read it again when the file changes).
    Revoke {
        /// The fleet's directory.
        #[arg(long)]
        dir: std::path::PathBuf,
        /// The device id.
        #[arg(long, required_unless_present = "site", conflicts_with = "site")]
        id: Option<i64>,
        /// A site instead (docs/remote.md): its link certificate and DDS identities are
        /// revoked, and every bridge refuses its name on the link (revoked-sites.p7s, copied
        /// into every site directory).
        #[arg(long)]
        site: Option<String>,
    },
    /// List a fleet's devices, how long each certificate is valid, and which are revoked.
    List {
        /// The fleet's directory.
        #[arg(long)]
        dir: std::path::PathBuf,
    },
    /// Issue the browser console's HTTPS certificate, signed by the fleet CA, in
    /// DIR/web-HOST/ (docs/web.md).
    Web {
        /// The fleet's directory.
        #[arg(long)]
        dir: std::path::PathBuf,
        /// A name or address browsers reach the operator by (repeat for more).
        #[arg(long = "host", required = true)]
        hosts: Vec<String>,
        /// Days the certificate is valid.
        #[arg(long, default_value_t = certs::Lifetime::DEVICE.days)]
        days: u32,
    },
    /// Issue a site bridge's certificate for the link between sites (CN=rove-site-NAME), in
    /// DIR/site-NAME/ (docs/remote.md); with --proxies, a secured site's DDS identities too.
    Site {
        /// The fleet's directory.
        #[arg(long)]
        dir: std::path::PathBuf,
        /// The site's name (lowercase letters, digits, '-').
        #[arg(long)]
        name: String,
        /// A name or address the site's bridge is reached by (repeat for more; optional).
        #[arg(long = "host")]
        hosts: Vec<String>,
        /// For a secured site: the ids of other sites' devices its bridge shows here, each
        /// given a proxy certificate (comma-separated; the link's certificate is made only if
        /// absent).
        #[arg(long, value_delimiter = ',')]
        proxies: Vec<rove_core::msg::DeviceId>,
        /// The highest level the proxies' operators may claim here: the site's `level` in
        /// the bridge file.
        #[arg(long, default_value = "remote", value_parser = parse_level)]
        level: rove_core::hierarchy::Level,
        /// Days the certificate is valid.
        #[arg(long, default_value_t = certs::Lifetime::DEVICE.days)]
        days: u32,
    },
}

/// `rove keys …`.
pub fn run(what: KeysCommand) -> anyhow::Result<()> {
    match what {
        KeysCommand::Init { dir, fleet, domain } => {
            certs::init(&dir, &fleet, domain)?;
            println!(
                "fleet {fleet:?} created in {} (domain {domain})",
                dir.display()
            );
            Ok(())
        }
        KeysCommand::Add {
            dir,
            id,
            days,
            renew,
            starts_in_days,
        } => {
            let lifetime = certs::Lifetime {
                days,
                starts_in_days,
            };
            let out = certs::add(&dir, id, lifetime, renew)?;
            let expiry = certs::Expiry::of(&std::fs::read(out.join("cert.pem"))?)?;
            println!(
                "device {id}: certificate ({}), key and permissions in {}",
                expiry.describe(),
                out.display()
            );
            Ok(())
        }
        KeysCommand::Request { dir, id } => {
            let path = certs::request(&dir, id)?;
            println!(
                "device {id}: private key in {} (it stays here); take {} to the fleet CA \
                 (`rove keys sign --request {} --id {id}`)",
                dir.join("key.pem").display(),
                path.display(),
                certs::REQUEST_FILE
            );
            Ok(())
        }
        KeysCommand::Sign {
            dir,
            request,
            id,
            days,
            renew,
        } => {
            let pem = std::fs::read(&request)
                .map_err(|e| anyhow::anyhow!("{}: {e}", request.display()))?;
            let out = certs::sign_request(&dir, &pem, id, certs::Lifetime::days(days), renew)?;
            println!(
                "device {id}: certificate and permissions in {} (no private key): copy its files \
                 to the device's directory, beside key.pem",
                out.display()
            );
            Ok(())
        }
        KeysCommand::Revoke { dir, id, site } => revoke(&dir, id, site),
        KeysCommand::List { dir } => {
            let issued = certs::list(&dir)?;
            println!("{:>8}  certificate", "device");
            for device in &issued {
                let revoked = if device.revoked { "REVOKED; " } else { "" };
                println!("{:>8}  {revoked}{}", device.id, device.expiry.describe());
            }
            println!("{} devices in {}", issued.len(), dir.display());
            Ok(())
        }
        KeysCommand::Site {
            dir,
            name,
            hosts,
            proxies,
            level,
            days,
        } => site(&dir, &name, &hosts, &proxies, level, days),
        KeysCommand::Web { dir, hosts, days } => {
            let out = certs::web(&dir, &hosts, certs::Lifetime::days(days))?;
            println!(
                "web console certificate for {hosts:?} in {0}: [web] certificate = \"{0}/cert.pem\", key = \"{0}/key.pem\"",
                out.display()
            );
            Ok(())
        }
    }
}

/// A hierarchy level's name, as in the config files.
fn parse_level(text: &str) -> Result<rove_core::hierarchy::Level, String> {
    use rove_core::hierarchy::Level;
    (Level::ALL.into_iter())
        .find(|l| format!("{l:?}").eq_ignore_ascii_case(text))
        .ok_or_else(|| format!("{text:?}: one of remote, stationary, mobile"))
}

/// `rove keys revoke`: device `id` or `site`.
fn revoke(dir: &std::path::Path, id: Option<i64>, site: Option<String>) -> anyhow::Result<()> {
    let (what, done) = match (id, site) {
        (Some(id), _) => (format!("device {id}"), certs::revoke(dir, id)?),
        (None, Some(name)) => {
            let site = rove_core::site::SiteName::new(&name)
                .map_err(|rule| anyhow::anyhow!("--site {name:?}: {rule}"))?;
            (format!("site {site}"), certs::revoke_site(dir, &site)?)
        }
        (None, None) => anyhow::bail!("name --id or --site"),
    };
    let plural = |n: usize, what: &str| format!("{n} {what}{}", if n == 1 { "" } else { "s" });
    println!(
        "{what} revoked: {} now names {}; copied into {} — copy {} to every device and \
         {} to every site's bridge (running devices and bridges read them again)",
        dir.join(certs::CRL_FILE).display(),
        plural(done.listed, "certificate"),
        match done.copied.len() {
            1 => "1 directory".to_string(),
            n => format!("{n} directories"),
        },
        certs::CRL_FILE,
        certs::REVOKED_SITES_FILE,
    );
    Ok(())
}

/// `rove keys site`: the link's certificate if absent or no `proxies`, then the proxies.
fn site(
    dir: &std::path::Path,
    name: &str,
    hosts: &[String],
    proxies: &[rove_core::msg::DeviceId],
    level: rove_core::hierarchy::Level,
    days: u32,
) -> anyhow::Result<()> {
    let site = rove_core::site::SiteName::new(name)
        .map_err(|rule| anyhow::anyhow!("--name {name:?}: {rule}"))?;
    let lifetime = certs::Lifetime::days(days);
    let link = dir.join(format!("site-{site}")).join("cert.pem");
    if proxies.is_empty() || !link.exists() {
        let out = certs::site(dir, &site, hosts, lifetime)?;
        println!(
            "site {site} certificate in {0}: [zenoh] certificate = \"{0}/cert.pem\", key = \"{0}/key.pem\", ca = \"{0}/ca.cert.pem\"",
            out.display()
        );
    }
    if !proxies.is_empty() {
        let out = certs::site_proxies(dir, &site, proxies, level, lifetime)?;
        println!(
            "site {site} DDS identities in {0} (proxies of {proxies:?} at most {level:?}): [security] dir = \"{0}\"",
            out.display()
        );
    }
    Ok(())
}
