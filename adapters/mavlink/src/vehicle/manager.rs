//! rove against an autopilot that is its own system manager (the GCS operator-control protocol,
//! [`crate::control`]; docs/mavlink.md, "An autopilot that manages its ground stations"): rove
//! sends no control message while another station holds `gcs_main`, asks for the role while an
//! operator drives, and answers a request the manager forwards to it.

use super::{Drive, MavlinkVehicle};
use crate::control::{self, Message, Standing};
use rove_core::error::LinkError;
use std::time::Instant;
use tracing::{info, warn};

impl MavlinkVehicle {
    /// Where rove stands with the autopilot's system manager now.
    pub(super) fn standing(&self) -> Standing {
        (self.link.control()).standing(self.config.system_id, Instant::now())
    }

    /// Whether the autopilot takes rove's control messages: it has no system manager, or its
    /// manager names rove. Otherwise they would be refused (and a QGC pilot who holds the role
    /// must not have rove's sticks mixed into theirs), so none are sent.
    pub(super) fn may_control(&self) -> bool {
        !matches!(self.standing(), Standing::Waiting { .. })
    }

    /// While an operator drives and another station (or nobody) holds the role: asks the
    /// manager for it (at once, again when the role changes hands, and when the request timed
    /// out), without takeover: the station's pilot is asked.
    pub(super) fn ask_for_control_if_due(&mut self) -> Result<(), LinkError> {
        let control = self.link.control();
        let standing = control.standing(self.config.system_id, Instant::now());
        if !self.asking.due(standing, Instant::now()) {
            return Ok(());
        }
        let (Some(component), Some((system, _))) = (control.manager(), self.link.target()) else {
            return Ok(());
        };
        if let Standing::Waiting { gcs_main } = standing {
            info!(
                gcs_main,
                "mavlink: another ground station is in control of the autopilot; rove asks its \
                 system manager for control and sends no control message until it has it"
            );
        }
        let request = control::request_payload(true, self.config.system_id, (system, component));
        self.link.send_raw(control::COMMAND_LONG, &request)
    }

    /// Answers the requests for control the manager forwarded to rove: each is acknowledged
    /// (the protocol asks the holder to), and rove lets go only while no operator drives.
    /// Decided (docs/mavlink.md): a station outside the hierarchy does not take a vehicle from
    /// a driving operator; nobody driving, the station's pilot may have it.
    pub(super) fn answer_forwarded(&mut self) -> Result<(), LinkError> {
        let forwarded = self.link.take_forwarded();
        if forwarded.is_empty() {
            return Ok(());
        }
        let (Some(component), Some((system, _))) =
            (self.link.control().manager(), self.link.target())
        else {
            return Ok(());
        };
        let mut result = Ok(());
        for msg in forwarded {
            let Message::Request {
                request: true, gcs, ..
            } = msg
            else {
                continue;
            };
            let ack = control::ack_payload(control::RESULT_ACCEPTED, (system, component));
            let sent = self.link.send_raw(control::COMMAND_ACK, &ack);
            let driving = matches!(self.drive, Drive::Driving(_));
            let released = if driving {
                warn!(
                    gcs,
                    "mavlink: a ground station asks for control of the autopilot while an \
                     operator drives: rove keeps it"
                );
                Ok(())
            } else {
                info!(
                    gcs,
                    "mavlink: a ground station asks for control of the autopilot and no operator \
                     drives: rove lets go"
                );
                let release =
                    control::request_payload(false, self.config.system_id, (system, component));
                self.link.send_raw(control::COMMAND_LONG, &release)
            };
            result = result.and(sent).and(released);
        }
        result
    }
}
