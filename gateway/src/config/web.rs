//! The browser console's settings in an operator's file (`[web]`, `[[web.device]]`, docs/web.md).

use super::*;

rove_core::config_types! {
    /// `[web]`: an HTTPS page that phones and tablets pair with and drive from (docs/web.md).
    pub table WebSection {
        listen: String => "Address and port of the HTTPS server, such as \"0.0.0.0:8443\".",
        certificate: Option<std::path::PathBuf> => "PEM certificate chain, with `key`: loaded if \
            both files exist, made (self-signed) and written there if neither does (absent: a new \
            self-signed certificate at every start).",
        key: Option<std::path::PathBuf> => "PEM private key of `certificate`.",
        session_s: Option<Int> => "How long a paired browser stays paired, seconds (absent: \
            43200, 12 hours).",
        #[serde(default)] device: Vec<WebDeviceSection> => "`[[web.device]]`: the operator \
            devices browsers pair as, one browser each.",
    }

    /// `[[web.device]]`: one operator device a browser pairs as.
    pub table WebDeviceSection {
        id: DeviceId => "Its device id (unique in the fleet).",
        name: Option<String> => "Its name (absent: web-ID).",
        level: Option<Level> => "Hierarchy level (absent: mobile).",
        device_class: Option<DeviceClass> => "Device class (absent: phone).",
        offset: Option<Int> => "Fine offset 0..=9 within the rank (absent: 0).",
        #[serde(default)] drive: Vec<DeviceId> => "Vehicles it drives while a finger is on a \
            stick (or the gamepad's deadman is held).",
        security: Option<std::path::PathBuf> => "DDS Security directory of this device \
            (`rove keys`); required when the operator has `[security]`.",
    }

    /// A validated `[web]`.
    #[derive(Debug, Clone)]
    pub struct WebConfig {
        listen: std::net::SocketAddr => "Where the HTTPS server listens.",
        certificate: Option<(std::path::PathBuf, std::path::PathBuf)> => "Certificate and key \
            files (made if both are missing), or none: self-signed in memory.",
        session: Duration => "How long a pairing lasts.",
        devices: Vec<OperatorConfig> => "One operator per `[[web.device]]`: the host's network \
            and handover settings with the device's identity, strength and `drive`.",
    }
}

/// How long a pairing lasts without `session_s`: a working day.
pub(super) const DEFAULT_WEB_SESSION_S: Int = 43_200;

impl WebSection {
    /// Validates `[web]` of the operator `host`; each device becomes an operator of its own.
    pub(super) fn validate(
        &mut self,
        host: &OperatorConfig,
        hierarchy: &Hierarchy,
        errors: &mut ConfigErrors,
    ) -> Option<WebConfig> {
        let listen = match self.listen.parse::<std::net::SocketAddr>() {
            Ok(a) => Some(a),
            Err(_) => {
                errors.add(
                    "listen",
                    &self.listen,
                    "must be ADDRESS:PORT, such as 0.0.0.0:8443",
                );
                None
            }
        };
        let certificate = match (&self.certificate, &self.key) {
            (Some(c), Some(k)) => Some((c.clone(), k.clone())),
            (None, None) => None,
            (Some(_), None) => {
                errors.add("key", ABSENT, "is required with `certificate`");
                None
            }
            (None, Some(_)) => {
                errors.add("certificate", ABSENT, "is required with `key`");
                None
            }
        };
        let session_s = *self.session_s.get_or_insert(DEFAULT_WEB_SESSION_S);
        let session = errors.int::<u64>("session_s", session_s, 1..=2_592_000, " s");
        if self.device.is_empty() {
            errors.add("device", ABSENT, "needs at least one [[web.device]]");
        }
        let mut seen = std::collections::BTreeSet::from([host.common.id]);
        let mut devices = Vec::new();
        for (i, d) in self.device.iter_mut().enumerate() {
            let at = format!("device[{i}]");
            if !seen.insert(d.id) {
                let rule = "is used twice (the operator's own id or another web device)";
                errors.add(format!("{at}.id"), d.id, rule);
            }
            let level = *d.level.get_or_insert(Level::Mobile);
            let class = *d.device_class.get_or_insert(DeviceClass::Phone);
            let offset = *d.offset.get_or_insert(0);
            let key = format!("{at}.offset");
            let strength = operator_strength(hierarchy, level, class, offset, &key, errors);
            if host.common.security.is_some() && d.security.is_none() {
                let rule = "is required: the operator has [security], and each web device is a \
                            participant with its own certificate";
                errors.add(format!("{at}.security"), ABSENT, rule);
            }
            let name = d
                .name
                .get_or_insert_with(|| format!("web-{}", d.id))
                .clone();
            let mut common = host.common.clone();
            (common.id, common.name, common.security) = (d.id, name, d.security.clone());
            devices.push(OperatorConfig {
                common,
                level,
                device_class: class,
                strength: strength.unwrap_or(Strength(1)),
                stream_period: host.stream_period,
                drive: d.drive.clone(),
                handover: host.handover,
                input: InputChoice::Constant(MovementCommand::CENTRED, Mode::Manual),
                api_socket: None,
                web: None,
            });
        }
        Some(WebConfig {
            listen: listen?,
            certificate,
            session: Duration::from_secs(session?),
            devices,
        })
    }
}
