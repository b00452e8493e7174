//! What another site sends: believed or refused ([`rove_core::site::Policy`]), then written
//! by the proxy of the device that speaks.

use super::{Bridge, MAX_DEVICES, proxy::Proxy, wire};
use rove_core::hierarchy::Strength;
use rove_core::msg::{DeviceId, DeviceInfo, DeviceType, RequestControl, VehicleStatus};
use rove_core::site::{Key, SiteName, Subject};
use std::collections::HashMap;
use tracing::info;

impl Bridge {
    /// A message from another site; `Err` says why it was refused.
    pub(super) fn message(&mut self, key: &str, put: Option<Vec<u8>>) -> Result<(), String> {
        let key = Key::parse(key).ok_or("not a rove key")?;
        let peer = self.policy.admit(&key).map_err(|e| e.to_string())?.clone();
        let site = &key.from;
        let subject = key.subject;
        let payload = || put.as_deref().ok_or("no payload");
        let from_site = |proxies: &HashMap<DeviceId, Proxy>, id| match proxies.get(&id) {
            Some(p) if &p.site == site => Ok(()),
            Some(_) => Err(format!("device {id} is another site's")),
            None => Err(format!("device {id} is not known yet")),
        };
        match subject {
            Subject::Info(id) => match &put {
                Some(bytes) => {
                    let info: DeviceInfo = wire::decode(bytes).ok_or("malformed DeviceInfo")?;
                    self.policy
                        .info(subject, &info)
                        .map_err(|e| e.to_string())?;
                    self.import(site, info)?;
                }
                None => {
                    from_site(&self.proxies, id)?;
                    self.drop_proxy(id);
                }
            },
            Subject::Status(id) => {
                from_site(&self.proxies, id)?;
                let status: VehicleStatus = wire::decode(payload()?).ok_or("malformed status")?;
                let proxy = self.proxies.get_mut(&id).ok_or("gone")?;
                if status.vehicle_id != id || proxy.info.device_type != DeviceType::Vehicle {
                    return Err("status of another device".into());
                }
                proxy.status(status);
            }
            Subject::Command {
                src,
                dest,
                strength,
            } => {
                from_site(&self.proxies, src)?;
                if !self.is_local_vehicle(dest) {
                    return Err(format!("vehicle {dest} is not on this site"));
                }
                let proxy = self.proxies.get_mut(&src).ok_or("gone")?;
                if proxy.info.device_type != DeviceType::Controller {
                    return Err(format!("device {src} is not an operator"));
                }
                match put {
                    Some(bytes) => {
                        let sent: wire::Command =
                            wire::decode(&bytes).ok_or("malformed command")?;
                        let strength = (self.policy.command(&peer, subject, &sent.command))
                            .map_err(|e| e.to_string())?;
                        proxy.command(strength, sent.command, sent.stamp);
                    }
                    None => {
                        let strength = self
                            .policy
                            .strength(&peer, strength)
                            .map_err(|e| e.to_string())?;
                        proxy.release(dest, strength);
                    }
                }
            }
            Subject::Request(sender) => {
                from_site(&self.proxies, sender)?;
                let msg: RequestControl = wire::decode(payload()?).ok_or("malformed request")?;
                let theirs = |v| self.proxies.get(&v).is_some_and(|p| &p.site == site);
                let msg = (self.policy.request(&peer, subject, theirs, msg))
                    .map_err(|e| e.to_string())?;
                let local_vehicle = self.is_local_vehicle(msg.dest_id);
                let proxy = self.proxies.get_mut(&sender).ok_or("gone")?;
                if msg.ack == rove_core::msg::Ack::Request && local_vehicle {
                    // The requester's writers ahead of its grant; its regular one at its
                    // priority, which is what auto-accept looks for (docs/design.md §4b).
                    let priority = u16::try_from(msg.src_priority).map(Strength);
                    proxy.prepare(msg.dest_id, priority.ok());
                }
                proxy.request(msg);
            }
        }
        Ok(())
    }

    pub(super) fn is_local_vehicle(&self, id: DeviceId) -> bool {
        (self.devices.get(&id)).is_some_and(|d| d.info.device_type == DeviceType::Vehicle)
    }

    /// Another site's DeviceInfo: its proxy made, or told.
    pub(super) fn import(&mut self, site: &SiteName, info: DeviceInfo) -> Result<(), String> {
        let id = info.device_id;
        if self.devices.contains_key(&id) {
            return Err(format!("device {id} is on this site"));
        }
        let full = self.proxies.len() >= MAX_DEVICES;
        match self.proxies.get_mut(&id) {
            Some(p) if &p.site != site => Err(format!("device {id} is site {}'s", p.site)),
            Some(p) if p.info.device_type != info.device_type => {
                Err(format!("device {id} changed its kind"))
            }
            Some(p) => {
                p.update(info);
                Ok(())
            }
            None if full => Err("too many devices".into()),
            None => {
                let proxy = Proxy::join(&self.common, site, info, &self.read_tx)
                    .map_err(|e| format!("cannot join as device {id}: {e:#}"))?;
                info!(id, %site, name = %proxy.info.name, kind = ?proxy.info.device_type, "device of another site joined here");
                self.ours.insert(proxy.participant(), id);
                self.proxies.insert(id, proxy);
                Ok(())
            }
        }
    }

    pub(super) fn drop_proxy(&mut self, id: DeviceId) {
        if let Some(proxy) = self.proxies.remove(&id) {
            info!(id, site = %proxy.site, "device of another site left");
            // Its participant stays ours until discovery reports it gone: what it published
            // last may still be on its way to us, and is not this site's.
            proxy.leave();
        }
    }
}
