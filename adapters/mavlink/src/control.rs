//! MAVLink's GCS operator-control protocol (`development.xml`; docs/mavlink.md, "An autopilot
//! that manages its ground stations"), and what rove does against an autopilot that is its own
//! *system manager*. Pure: no I/O; times are passed in.
//!
//! The `ardupilotmega` dialect rove decodes has neither CONTROL_STATUS (512) nor
//! MAV_CMD_REQUEST_OPERATOR_CONTROL (32100): the crate's parser refuses the one as an unknown id
//! and a COMMAND_LONG or COMMAND_ACK carrying the other as a field outside its enum. So they are
//! read and written here by hand, from their XML definitions.
//!
//! The protocol: the one component that streams CONTROL_STATUS with SYSTEM_MANAGER says which
//! ground station (`gcs_main`) may send manual control. A station asks it for that role with
//! MAV_CMD_REQUEST_OPERATOR_CONTROL; it is granted at once (ACCEPTED) when nobody holds it or the
//! holder allows takeover, else refused (FAILED) and the request is forwarded to the holder,
//! which must ACK it and then releases the role or keeps it.

use std::time::{Duration, Instant};

/// CONTROL_STATUS's message id.
pub const CONTROL_STATUS: u32 = 512;
/// Its CRC_EXTRA, from its fields (`uint8_t flags`, `uint8_t gcs_main`, `uint8_t[10]
/// gcs_secondary`), computed as mavgen does (checked with pymavlink's x25crc, which gives
/// COMMAND_ACK's 143).
pub const CONTROL_STATUS_CRC_EXTRA: u8 = 21;
/// MAV_CMD_REQUEST_OPERATOR_CONTROL.
pub const REQUEST_OPERATOR_CONTROL: u16 = 32100;
/// GCS_CONTROL_STATUS_FLAGS_SYSTEM_MANAGER.
pub const FLAG_SYSTEM_MANAGER: u8 = 1;
/// GCS_CONTROL_STATUS_FLAGS_TAKEOVER_ALLOWED.
pub const FLAG_TAKEOVER_ALLOWED: u8 = 2;
/// MAV_RESULT_ACCEPTED.
pub const RESULT_ACCEPTED: u8 = 0;
/// MAV_RESULT_FAILED: the holder of control is asked (or, from rove to a station, the hierarchy
/// said no).
pub const RESULT_FAILED: u8 = 4;

/// COMMAND_LONG's id and CRC_EXTRA (common.xml).
pub const COMMAND_LONG: (u32, u8) = (76, 152);
/// COMMAND_ACK's id and CRC_EXTRA (common.xml).
pub const COMMAND_ACK: (u32, u8) = (77, 143);

/// How long a system manager's CONTROL_STATUS counts (it is streamed at about 1 Hz): after
/// that, rove no longer waits on it.
pub const STATUS_LIFETIME: Duration = Duration::from_secs(3);
/// How long rove's request waits (the command's param 3: 3–60 s); rove asks again after it,
/// and at once when the role changes hands.
pub const REQUEST_TIMEOUT: Duration = Duration::from_secs(10);

/// A message of the protocol.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Message {
    /// CONTROL_STATUS.
    Status {
        /// GCS_CONTROL_STATUS_FLAGS.
        flags: u8,
        /// The system id of the station in control; 0: none.
        gcs_main: u8,
    },
    /// A COMMAND_LONG MAV_CMD_REQUEST_OPERATOR_CONTROL.
    Request {
        /// Request (param 1 = 1) or release (0).
        request: bool,
        /// Later takeovers are granted without asking (param 2).
        takeover: bool,
        /// Seconds the request waits (param 3).
        timeout_s: f32,
        /// The requesting station's system id (param 4).
        gcs: u8,
        /// Whom it is for.
        target: (u8, u8),
    },
    /// A COMMAND_ACK for MAV_CMD_REQUEST_OPERATOR_CONTROL.
    Ack {
        /// MAV_RESULT.
        result: u8,
        /// Whom it answers (0: anyone, as MAVLink 1 acks).
        target_system: u8,
    },
}

/// The CRC_EXTRA of a message id this module reads that the dialect does not know.
pub fn crc_extra(id: u32) -> Option<u8> {
    (id == CONTROL_STATUS).then_some(CONTROL_STATUS_CRC_EXTRA)
}

/// Reads a frame's payload (`id`, CRC already checked) as a message of the protocol, if it is
/// one. MAVLink 2 cuts trailing zero bytes off a payload: they are put back.
pub fn parse(id: u32, payload: &[u8]) -> Option<Message> {
    let field = |at: usize| payload.get(at).copied().unwrap_or(0);
    let f32_at =
        |at: usize| f32::from_le_bytes([field(at), field(at + 1), field(at + 2), field(at + 3)]);
    let u16_at = |at: usize| u16::from_le_bytes([field(at), field(at + 1)]);
    match id {
        CONTROL_STATUS => Some(Message::Status {
            flags: field(0),
            gcs_main: field(1),
        }),
        // param1..7 (7 × f32), command (u16), target_system, target_component, confirmation.
        76 if u16_at(28) == REQUEST_OPERATOR_CONTROL => Some(Message::Request {
            request: f32_at(0) >= 0.5,
            takeover: f32_at(4) >= 0.5,
            timeout_s: f32_at(8),
            gcs: clamp_u8(f32_at(12)),
            target: (field(30), field(31)),
        }),
        // command (u16), result, progress, result_param2 (i32), target_system, target_component.
        77 if u16_at(0) == REQUEST_OPERATOR_CONTROL => Some(Message::Ack {
            result: field(2),
            target_system: field(8),
        }),
        _ => None,
    }
}

fn clamp_u8(v: f32) -> u8 {
    if v.is_finite() {
        v.clamp(0.0, 255.0) as u8
    } else {
        0
    }
}

/// The payload of a COMMAND_LONG MAV_CMD_REQUEST_OPERATOR_CONTROL from station `gcs` to
/// `target`: a request (that the holder be asked, not a takeover) or a release.
pub fn request_payload(request: bool, gcs: u8, target: (u8, u8)) -> Vec<u8> {
    let mut p = Vec::with_capacity(33);
    let timeout = REQUEST_TIMEOUT.as_secs_f32();
    for param in [
        f32::from(u8::from(request)),
        0.0,
        timeout,
        f32::from(gcs),
        0.0,
        0.0,
        0.0,
    ] {
        p.extend(param.to_le_bytes());
    }
    p.extend(REQUEST_OPERATOR_CONTROL.to_le_bytes());
    p.extend([target.0, target.1, 0]);
    p
}

/// The payload of a COMMAND_ACK of MAV_CMD_REQUEST_OPERATOR_CONTROL with `result`, to `target`.
pub fn ack_payload(result: u8, target: (u8, u8)) -> Vec<u8> {
    let mut p = Vec::with_capacity(10);
    p.extend(REQUEST_OPERATOR_CONTROL.to_le_bytes());
    p.extend([result, 0]);
    p.extend(0i32.to_le_bytes());
    p.extend([target.0, target.1]);
    p
}

/// Where rove stands with the autopilot's system manager.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Standing {
    /// No system manager heard (recently): rove drives as a ground station always did.
    Unmanaged,
    /// The manager names rove as `gcs_main`.
    InControl,
    /// The manager names another station (or none, 0): rove's control messages would be
    /// refused, so none are sent.
    Waiting {
        /// Who holds the role (0: nobody).
        gcs_main: u8,
    },
}

/// What rove knows of the autopilot's system manager: its last CONTROL_STATUS.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq)]
pub struct Control {
    heard: Option<Heard>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Heard {
    component: u8,
    gcs_main: u8,
    at: Instant,
}

impl Control {
    /// The autopilot's component `component` sent CONTROL_STATUS `flags`/`gcs_main` at `at`. A
    /// status without SYSTEM_MANAGER is one component's own and does not govern rove.
    pub fn heard(&mut self, component: u8, flags: u8, gcs_main: u8, at: Instant) {
        if flags & FLAG_SYSTEM_MANAGER != 0 {
            self.heard = Some(Heard {
                component,
                gcs_main,
                at,
            });
        }
    }

    /// Where rove (system `me`) stands at `now`.
    pub fn standing(&self, me: u8, now: Instant) -> Standing {
        match self.heard {
            Some(h) if now.saturating_duration_since(h.at) <= STATUS_LIFETIME => {
                if h.gcs_main == me {
                    Standing::InControl
                } else {
                    Standing::Waiting {
                        gcs_main: h.gcs_main,
                    }
                }
            }
            _ => Standing::Unmanaged,
        }
    }

    /// The system manager's component, once heard.
    pub fn manager(&self) -> Option<u8> {
        self.heard.map(|h| h.component)
    }
}

/// When rove last asked the system manager for control, and who held the role then.
#[derive(Debug, Default, Clone, Copy)]
pub struct Asking {
    last: Option<(Instant, u8)>,
}

impl Asking {
    /// Whether rove should ask for control now, standing as `standing`: it waits for the role,
    /// and has not asked since the role last changed hands or for [`REQUEST_TIMEOUT`]. Asking
    /// is recorded.
    pub fn due(&mut self, standing: Standing, now: Instant) -> bool {
        let Standing::Waiting { gcs_main } = standing else {
            return false;
        };
        let due = self.last.is_none_or(|(at, holder)| {
            holder != gcs_main || now.saturating_duration_since(at) >= REQUEST_TIMEOUT
        });
        if due {
            self.last = Some((now, gcs_main));
        }
        due
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const ME: u8 = 255;
    const QGC: u8 = 250;

    #[test]
    fn a_request_and_an_ack_read_back_as_written() {
        let p = request_payload(true, ME, (1, 1));
        assert_eq!(p.len(), 33);
        let Some(Message::Request {
            request,
            takeover,
            timeout_s,
            gcs,
            target,
        }) = parse(76, &p)
        else {
            panic!("not a request: {:?}", parse(76, &p));
        };
        assert!(request && !takeover);
        assert_eq!((timeout_s, gcs, target), (10.0, ME, (1, 1)));
        let release = parse(76, &request_payload(false, ME, (1, 1)));
        assert!(matches!(
            release,
            Some(Message::Request { request: false, .. })
        ));
        let ack = ack_payload(RESULT_ACCEPTED, (1, 1));
        assert_eq!(
            parse(77, &ack),
            Some(Message::Ack {
                result: RESULT_ACCEPTED,
                target_system: 1
            })
        );
    }

    #[test]
    fn other_commands_acks_and_ids_are_not_the_protocols() {
        let mut p = request_payload(true, ME, (1, 1));
        p[28..30].copy_from_slice(&176u16.to_le_bytes()); // MAV_CMD_DO_SET_MODE
        assert_eq!(parse(76, &p), None);
        assert_eq!(parse(77, &176u16.to_le_bytes()), None);
        assert_eq!(parse(0, &[]), None);
        assert_eq!(crc_extra(0), None);
        assert_eq!(crc_extra(CONTROL_STATUS), Some(CONTROL_STATUS_CRC_EXTRA));
    }

    #[test]
    fn a_truncated_status_reads_its_zeros_back() {
        // MAVLink 2 sends CONTROL_STATUS {flags 1, gcs_main 0, ...} as one byte.
        assert_eq!(
            parse(CONTROL_STATUS, &[1]),
            Some(Message::Status {
                flags: 1,
                gcs_main: 0
            })
        );
        assert_eq!(
            parse(CONTROL_STATUS, &[]),
            Some(Message::Status {
                flags: 0,
                gcs_main: 0
            })
        );
    }

    #[test]
    fn a_garbled_request_reads_as_a_station_id_within_range() {
        let mut p = request_payload(true, ME, (1, 1));
        p[12..16].copy_from_slice(&f32::NAN.to_le_bytes());
        assert!(matches!(
            parse(76, &p),
            Some(Message::Request { gcs: 0, .. })
        ));
        p[12..16].copy_from_slice(&1e9f32.to_le_bytes());
        assert!(matches!(
            parse(76, &p),
            Some(Message::Request { gcs: 255, .. })
        ));
    }

    #[test]
    fn without_a_manager_rove_drives_as_before() {
        let t = Instant::now();
        let mut c = Control::default();
        assert_eq!(c.standing(ME, t), Standing::Unmanaged);
        assert!(!Asking::default().due(c.standing(ME, t), t));
        // A component's own status (no SYSTEM_MANAGER) does not govern rove.
        c.heard(1, 0, QGC, t);
        assert_eq!(c.standing(ME, t), Standing::Unmanaged);
    }

    #[test]
    fn rove_waits_while_another_station_holds_the_role_and_asks_once_per_holder_or_timeout() {
        let t = Instant::now();
        let mut c = Control::default();
        let mut asking = Asking::default();
        c.heard(1, FLAG_SYSTEM_MANAGER, QGC, t);
        assert_eq!(c.manager(), Some(1));
        assert_eq!(c.standing(ME, t), Standing::Waiting { gcs_main: QGC });
        assert!(asking.due(c.standing(ME, t), t), "asks at once");
        let later = t + Duration::from_secs(2);
        c.heard(1, FLAG_SYSTEM_MANAGER, QGC, later);
        let again = asking.due(c.standing(ME, later), later);
        assert!(!again, "not again while the same station holds it");
        let timeout = t + REQUEST_TIMEOUT;
        c.heard(1, FLAG_SYSTEM_MANAGER, QGC, timeout);
        let again = asking.due(c.standing(ME, timeout), timeout);
        assert!(again, "again once the request timed out");
        // The station lets go: rove asks at once.
        let freed = timeout + Duration::from_millis(100);
        c.heard(1, FLAG_SYSTEM_MANAGER, 0, freed);
        assert_eq!(c.standing(ME, freed), Standing::Waiting { gcs_main: 0 });
        assert!(asking.due(c.standing(ME, freed), freed));
        // Granted.
        c.heard(1, FLAG_SYSTEM_MANAGER | FLAG_TAKEOVER_ALLOWED, ME, freed);
        assert_eq!(c.standing(ME, freed), Standing::InControl);
        assert!(!asking.due(c.standing(ME, freed), freed));
    }

    #[test]
    fn a_manager_that_falls_silent_no_longer_holds_rove_back() {
        let t = Instant::now();
        let mut c = Control::default();
        c.heard(1, FLAG_SYSTEM_MANAGER, QGC, t);
        assert_eq!(
            c.standing(ME, t + STATUS_LIFETIME),
            Standing::Waiting { gcs_main: QGC }
        );
        let silent = t + STATUS_LIFETIME + Duration::from_millis(1);
        assert_eq!(c.standing(ME, silent), Standing::Unmanaged);
        assert!(!Asking::default().due(c.standing(ME, silent), silent));
    }
}
