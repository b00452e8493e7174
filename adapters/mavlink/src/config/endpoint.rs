//! Where the autopilot (`connection`) and the ground stations (`[[output.gcs]]`) are: the
//! endpoint forms and their parsing.

use std::fmt;

rove_core::config_types! {
    /// Where the autopilot or a ground station is.
    #[derive(Debug, Clone, PartialEq, Eq)]
    pub enum Endpoint {
        UdpIn => "We listen on this address; replies go to the last sender." (String),
        UdpOut => "We send to this address from an ephemeral port." (String),
        TcpOut => "We connect to this TCP server (SITL: 127.0.0.1:5760)." (String),
        TcpIn => "We listen on this TCP address for one client at a time (a ground station's \
            port only)." (String),
        Serial => "A serial device at a baud rate." {
            device: String => "Device path.",
            baud: u32 => "Baud rate.",
        },
    }
}

impl fmt::Display for Endpoint {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Endpoint::UdpIn(a) => write!(f, "udpin:{a}"),
            Endpoint::UdpOut(a) => write!(f, "udpout:{a}"),
            Endpoint::TcpOut(a) => write!(f, "tcpout:{a}"),
            Endpoint::TcpIn(a) => write!(f, "tcpin:{a}"),
            Endpoint::Serial { device, baud } => write!(f, "serial:{device}:{baud}"),
        }
    }
}

impl Endpoint {
    /// Parses `udpin:`, `udp:`, `udpout:`, `tcpout:`, `tcp:`, `tcpin:` and `serial:` addresses.
    ///
    /// # Errors
    /// The rule the text breaks.
    pub fn parse(text: &str) -> Result<Endpoint, String> {
        let schemes = "udpin, udpout, tcpout, tcpin";
        let Some((scheme, rest)) = text.split_once(':') else {
            return Err(format!(
                "must be SCHEME:ADDRESS with SCHEME {schemes} or serial"
            ));
        };
        let host_port = |rest: &str| -> Result<String, String> {
            let needs = || format!("{scheme}: needs HOST:PORT");
            let (host, port) = rest.rsplit_once(':').ok_or_else(needs)?;
            if host.is_empty() {
                return Err(format!("{scheme}: needs a host before :PORT"));
            }
            match port.parse::<u16>() {
                Ok(p) if p > 0 => Ok(rest.to_string()),
                _ => Err(format!("{scheme}: port must be 1..=65535, not {port:?}")),
            }
        };
        match scheme {
            "udpin" | "udp" => Ok(Endpoint::UdpIn(host_port(rest)?)),
            "udpout" => Ok(Endpoint::UdpOut(host_port(rest)?)),
            "tcpout" | "tcp" => Ok(Endpoint::TcpOut(host_port(rest)?)),
            "tcpin" => Ok(Endpoint::TcpIn(host_port(rest)?)),
            "serial" => {
                let needs = "serial: needs DEVICE:BAUD, e.g. serial:/dev/ttyACM0:115200";
                let (device, baud) = rest.rsplit_once(':').ok_or(needs)?;
                if device.is_empty() {
                    return Err("serial: needs a device path".into());
                }
                let device = device.to_string();
                match baud.parse::<u32>() {
                    Ok(baud) if baud > 0 => Ok(Endpoint::Serial { device, baud }),
                    _ => Err(format!(
                        "serial: baud must be a positive number, not {baud:?}"
                    )),
                }
            }
            other => Err(format!(
                "unknown scheme {other:?}: use {schemes} (tcp) or serial"
            )),
        }
    }
}
