//! What another site sends: believed or refused ([`rove_core::site::Policy`]), then written
//! by the proxy of the device that speaks.

use super::{Bridge, MAX_DEVICES, proxy::Proxy};
use rove_core::hierarchy::Strength;
use rove_core::msg::{DeviceId, DeviceInfo, DeviceType};
use rove_core::site::{SiteName, Subject, wire};
use std::collections::HashMap;
use tracing::info;
use wire::Inbound;

impl Bridge {
    /// A message from another site, read and checked by [`rove_core::site::Policy::inbound`],
    /// then given to the proxy of the device that speaks; `Err` says why it was refused.
    pub(super) fn message(&mut self, key: &str, put: Option<Vec<u8>>) -> Result<(), String> {
        let theirs = |site: &SiteName, id| self.proxies.get(&id).is_some_and(|p| &p.site == site);
        let (site, inbound) =
            (self.policy.inbound(key, put.as_deref(), theirs)).map_err(|e| e.to_string())?;
        let from_site = |proxies: &HashMap<DeviceId, Proxy>, id| match proxies.get(&id) {
            Some(p) if p.site == site => Ok(()),
            Some(_) => Err(format!("device {id} is another site's")),
            None => Err(format!("device {id} is not known yet")),
        };
        match inbound {
            Inbound::Info(info) => self.import(&site, info)?,
            Inbound::Withdrawn(id) => {
                from_site(&self.proxies, id)?;
                self.drop_proxy(id);
            }
            Inbound::Status(status) => {
                let id = status.vehicle_id;
                from_site(&self.proxies, id)?;
                let proxy = self.proxies.get_mut(&id).ok_or("gone")?;
                if proxy.info.device_type != DeviceType::Vehicle {
                    return Err(format!("status of device {id}, which is not a vehicle"));
                }
                proxy.status(status);
            }
            Inbound::Command {
                src,
                dest,
                strength,
                command,
            } => {
                from_site(&self.proxies, src)?;
                if !self.is_local_vehicle(dest) {
                    return Err(format!("vehicle {dest} is not on this site"));
                }
                let proxy = self.proxies.get_mut(&src).ok_or("gone")?;
                if proxy.info.device_type != DeviceType::Controller {
                    return Err(format!("device {src} is not an operator"));
                }
                match command {
                    Some(sent) => proxy.command(strength, sent.command, sent.stamp),
                    None => proxy.release(dest, strength),
                }
            }
            Inbound::Request(msg) => {
                let sender = msg.sender_id();
                from_site(&self.proxies, sender)?;
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
                let security = match &self.secured {
                    Some(secured) => Some(secured.proxy(id).ok_or_else(|| {
                        format!("device {id}: this secured site has no proxy certificate for it")
                    })?),
                    None => None,
                };
                let proxy = Proxy::join(&self.common, site, info, security, &self.read_tx)
                    .map_err(|e| format!("cannot join as device {id}: {e:#}"))?;
                info!(id, %site, name = %proxy.info.name, kind = ?proxy.info.device_type, "device of another site joined here");
                self.ours.insert(proxy.participant(), id);
                self.proxies.insert(id, proxy);
                Ok(())
            }
        }
    }

    /// Every device of `site` leaves this site.
    pub(super) fn drop_site(&mut self, site: &SiteName) {
        let gone: Vec<DeviceId> = (self.proxies.iter())
            .filter(|(_, p)| &p.site == site)
            .map(|(id, _)| *id)
            .collect();
        for id in gone {
            self.drop_proxy(id);
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

    /// Sends `site` everything of ours it may see.
    pub(super) async fn show_all(&mut self, site: &SiteName) {
        let Some(peer) = self.policy.peer(site) else {
            return;
        };
        let mut messages = Vec::new();
        for (id, device) in &self.devices {
            if self.policy.shows(peer, &device.info) {
                messages.push((Subject::Info(*id), wire::encode(&device.info)));
                if let Some(status) = &device.status {
                    messages.push((Subject::Status(*id), wire::encode(status)));
                }
            }
        }
        for (subject, payload) in messages {
            let key = self.key(site, subject);
            self.link.send(&key, Some(payload)).await;
        }
    }
}
