//! A site bridge's file (`rove bridge`, docs/remote.md): `[site]`, `[zenoh]`, `[[zenoh.site]]`.

use super::*;

rove_core::config_types! {
    /// A site bridge's file as written (`rove bridge`, docs/remote.md).
    pub table RawBridge {
        site: SiteSection => "`[site]`.",
        #[serde(default)] network: NetworkSection => "`[network]`: the site's DDS network.",
        #[serde(default)] log: LogSection => "`[log]`.",
        #[serde(default)] hierarchy: HierarchyTable => "`[hierarchy]`: the strengths this \
            site's vehicles believe (absent: docs/design.md §3); another site's operators are \
            taken at most at its `level`.",
        zenoh: ZenohSection => "`[zenoh]`: the link to other sites.",
        security: Option<SecuritySection> => "`[security]`: a secured site (DDS Security):             `dir` is the site's directory from `rove keys site --proxies` (`DIR/site-NAME`).",
    }

    /// `[site]`.
    pub table SiteSection {
        name: String => "This site's name: lowercase letters, digits and '-' (its \
            certificate's common name is `rove-site-NAME`, from `rove keys site`).",
    }

    /// `[zenoh]`: the link between sites, Zenoh over mutual TLS.
    pub table ZenohSection {
        #[serde(default)] listen: Vec<String> => "Endpoints other sites connect to, such as \
            \"tls/192.0.2.1:7447\" (absent: none).",
        #[serde(default)] connect: Vec<String> => "Endpoints of other sites' bridges to connect \
            to (absent: none). At least one of `listen` and `connect`.",
        ca: std::path::PathBuf => "The fleet's CA certificate (`ca.cert.pem`): a site's \
            certificate must be signed by it.",
        certificate: std::path::PathBuf => "This site's certificate (`rove keys site`).",
        key: std::path::PathBuf => "This site's private key.",
        lease_ms: Option<Int> => "How long a silent link stays up, ms, 1000 to 60000 (absent: \
            3000). The vehicles' command timeout, not this, stops them on a cut link; when the \
            lease runs out the other site's devices leave this site's lists.",
        #[serde(default)] site: Vec<PeerSection> => "`[[zenoh.site]]`: the sites this one \
            meets. Any other is refused.",
    }

    /// `[[zenoh.site]]`: another site.
    pub table PeerSection {
        name: String => "Its name (its certificate's common name is `rove-site-NAME`).",
        #[serde(default)] ids: Vec<DeviceId> => "The device ids it may speak for: its \
            operators, and its vehicles this site may drive.",
        #[serde(default)] offer: Vec<DeviceId> => "This site's vehicles it may see and drive \
            (absent: none).",
        level: Option<Level> => "The highest hierarchy level its operators may claim here \
            (absent: remote); a stronger claim is taken at this level.",
    }

    /// A validated `[zenoh]`.
    #[derive(Debug, Clone)]
    pub struct ZenohLink {
        listen: Vec<String> => "Endpoints listened on.",
        connect: Vec<String> => "Endpoints connected to.",
        ca: std::path::PathBuf => "The fleet's CA.",
        certificate: std::path::PathBuf => "This site's certificate.",
        key: std::path::PathBuf => "This site's key.",
        lease: Duration => "The link's lease.",
    }

    /// A validated bridge configuration.
    #[derive(Debug, Clone)]
    pub struct BridgeConfig {
        common: Common => "The site's DDS network (`id` 0: the bridge is no device).",
        policy: rove_core::site::Policy => "This site, and what other sites may say here.",
        link: ZenohLink => "The link.",
    }
}

/// Reads and validates a bridge config.
///
/// # Errors
/// As [`load_vehicle`].
pub fn load_bridge(path: &Path) -> anyhow::Result<BridgeConfig> {
    let text = read(path)?;
    let mut raw: RawBridge = parse(path, &text)?;
    let mut config = raw.validate().map_err(|e| located(path, &text, e))?;
    config.resolve_paths(path);
    Ok(config)
}

impl BridgeConfig {
    /// Makes the link's files relative to the config file's directory.
    pub fn resolve_paths(&mut self, config_path: &Path) {
        self.common.resolve_paths(config_path);
        let dir = config_path.parent().unwrap_or(Path::new("."));
        let link = &mut self.link;
        for file in [&mut link.ca, &mut link.certificate, &mut link.key] {
            *file = dir.join(&*file);
        }
    }
}

impl ZenohLink {
    /// Whether this process can read the link's certificate files (the bridge checks at start,
    /// `check-config` does not: an installed config names files made later).
    ///
    /// # Errors
    /// The first file that cannot be opened, with its `[zenoh]` key and the cause.
    pub fn check_files(&self) -> anyhow::Result<()> {
        for (key, file) in [
            ("ca", &self.ca),
            ("certificate", &self.certificate),
            ("key", &self.key),
        ] {
            let readable = std::fs::File::open(file).and_then(|f| {
                if f.metadata()?.is_file() {
                    Ok(())
                } else {
                    Err(std::io::Error::other("not a file"))
                }
            });
            readable.map_err(|e| {
                anyhow::anyhow!(
                    "[zenoh] {key} = {}: {e} (a site's files come from `rove keys site`, and \
                     must be readable by the user the bridge runs as)",
                    file.display()
                )
            })?;
        }
        Ok(())
    }
}

impl RawBridge {
    /// Validates, filling defaults into `self`.
    ///
    /// # Errors
    /// [`rove_core::Error::Config`] listing every invalid key.
    pub fn validate(&mut self) -> rove_core::Result<BridgeConfig> {
        use rove_core::site::{Peer, Policy, SiteName};
        let mut errors = ConfigErrors::default();
        let name = |errors: &mut ConfigErrors, key: &str, name: &str| {
            SiteName::new(name)
                .map_err(|rule| errors.add(key, format!("{name:?}"), rule))
                .ok()
        };
        let me = name(&mut errors, "site.name", &self.site.name);
        let mut device = DeviceSection {
            id: 1,
            name: Some(format!("bridge-{}", self.site.name)),
        };
        let mut common = validate_common(&mut device, &mut self.network, &self.log, &mut errors);
        common.id = 0;
        common.security = self.security.as_ref().map(|s| s.dir.clone());
        let hierarchy = errors.section("hierarchy", Hierarchy::from_table(&self.hierarchy));
        let z = &mut self.zenoh;
        if z.listen.is_empty() && z.connect.is_empty() {
            let rule = "name at least one endpoint in `listen` or `connect`";
            errors.add("zenoh.listen", "[]", rule);
        }
        for (list, endpoints) in [("listen", &z.listen), ("connect", &z.connect)] {
            for (i, endpoint) in endpoints.iter().enumerate() {
                if let Err(rule) = check_endpoint(endpoint) {
                    errors.add(format!("zenoh.{list}[{i}]"), format!("{endpoint:?}"), rule);
                }
            }
        }
        let lease = *z.lease_ms.get_or_insert(3000);
        let lease = errors.int::<u64>("zenoh.lease_ms", lease, 1000..=60_000, " ms");
        let mut peers = Vec::new();
        let mut unique = Unique::default();
        // An id belongs to one site: to one other site, or to this one (offered).
        let mut owners = Unique::default();
        let offered: std::collections::BTreeSet<DeviceId> = z
            .site
            .iter()
            .flat_map(|p| p.offer.iter().copied())
            .collect();
        for (i, peer) in z.site.iter_mut().enumerate() {
            let key = format!("zenoh.site[{i}].name");
            let Some(site) = name(&mut errors, &key, &peer.name) else {
                continue;
            };
            if Some(&site) == me.as_ref() {
                errors.add(&key, format!("{:?}", peer.name), "is this site's own name");
            }
            let shown = (key.as_str(), format!("{:?}", peer.name));
            unique.check(&mut errors, site.clone(), format!("site[{i}]"), shown, "");
            for (list, ids) in [("ids", &peer.ids), ("offer", &peer.offer)] {
                for (j, id) in ids.iter().enumerate() {
                    if *id <= 0 {
                        let key = format!("zenoh.site[{i}].{list}[{j}]");
                        errors.add(key, id, "must be a positive device id");
                    }
                }
            }
            for (j, id) in peer.ids.iter().enumerate() {
                let key = format!("zenoh.site[{i}].ids[{j}]");
                if offered.contains(id) {
                    let rule = "is offered as this site's vehicle: an id belongs to one site";
                    errors.add(&key, id, rule);
                }
                let shown = (key.as_str(), id);
                owners.check(&mut errors, *id, format!("site[{i}].ids"), shown, "");
            }
            peers.push(Peer {
                name: site,
                ids: peer.ids.iter().copied().collect(),
                offer: peer.offer.iter().copied().collect(),
                level: *peer.level.get_or_insert(Level::Remote),
            });
        }
        let link = ZenohLink {
            listen: z.listen.clone(),
            connect: z.connect.clone(),
            ca: z.ca.clone(),
            certificate: z.certificate.clone(),
            key: z.key.clone(),
            lease: Duration::from_millis(lease.unwrap_or(3000)),
        };
        let Some(me) = me else {
            // `site.name` is invalid, and `name` recorded why.
            return Err(rove_core::Error::Config(errors));
        };
        let policy = Policy {
            me,
            hierarchy: hierarchy.unwrap_or(Hierarchy::STANDARD),
            peers,
        };
        errors.into_result(BridgeConfig {
            common,
            policy,
            link,
        })
    }
}

/// A link endpoint as the bridge takes it: `tls/HOST:PORT` (the link is always mutual TLS).
pub(super) fn check_endpoint(endpoint: &str) -> Result<(), &'static str> {
    let Some(address) = endpoint.strip_prefix("tls/") else {
        return Err("must be `tls/HOST:PORT`: sites meet only over mutual TLS");
    };
    let (host, port) = address
        .rsplit_once(':')
        .ok_or("must be `tls/HOST:PORT` (no port)")?;
    if host.is_empty() || port.parse::<u16>().is_err() {
        return Err("must be `tls/HOST:PORT` with a port 0 to 65535");
    }
    Ok(())
}
