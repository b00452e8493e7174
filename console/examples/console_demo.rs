//! A fake operator behind the real console and API: shows how the gateway wires
//! [`rove_console::run_terminal`] and [`rove_console::ApiSocket`] to its event loop.
//!
//! `cargo run -p rove-console --example console_demo [SOCKET]`: two vehicles and another
//! operator appear; after 3 s "op-b" asks for rover-1. Drive / release / accept / refuse work
//! against a toy model of the operator (no DDS, nothing moves). With SOCKET, the API listens
//! there too: `socat - UNIX-CONNECT:SOCKET`.

use rove_console::model::{DeviceKind, InputStatus, Outcome};
use rove_console::{ApiSocket, Command, CommandRequest, ConsoleState, Event, Identity, Stamped};
use rove_core::MonoTime;
use rove_core::handover::Prompt;
use rove_core::hierarchy::{DeviceClass, Level, Strength};
use std::collections::BTreeSet;
use std::time::{Duration, Instant};
use tokio::sync::{broadcast, mpsc};

fn main() -> std::io::Result<()> {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    runtime.block_on(run())
}

async fn run() -> std::io::Result<()> {
    let start = Instant::now();
    let clock = move || MonoTime::from_nanos(start.elapsed().as_nanos() as u64);
    let me = Identity {
        id: 1,
        name: "laptop-1".into(),
        level: Level::Mobile,
        class: DeviceClass::Laptop,
        strength: Strength(320),
    };
    let state = ConsoleState::new(me, Duration::from_secs(3));
    // Subscribe everyone before the first event.
    let (events, console_events) = broadcast::channel::<Stamped>(1024);
    let (commands, mut requests) = mpsc::channel::<CommandRequest>(64);
    let (_buttons, actions) = mpsc::channel(16);
    if let Some(path) = std::env::args_os().nth(1) {
        let socket = ApiSocket::bind(path.as_ref()).map_err(std::io::Error::other)?;
        tokio::spawn(socket.serve(
            rove_console::server::Hub::start(state.clone(), events.subscribe()),
            commands.clone(),
        ));
    }
    let console = tokio::spawn(rove_console::run_terminal(
        state,
        clock,
        console_events,
        commands,
        actions,
    ));

    // The toy operator.
    let emit = |event| {
        let _ = events.send(Stamped { at: clock(), event });
    };
    let mut driving = BTreeSet::new();
    let mut owners = [(100, 100), (101, 7)];
    let mut heartbeat = tokio::time::interval(Duration::from_secs(1));
    let ask_at = tokio::time::sleep(Duration::from_secs(3));
    tokio::pin!(ask_at);
    let mut asked = false;
    loop {
        tokio::select! {
            _ = heartbeat.tick() => {
                emit(Event::DeviceSeen { id: 7, name: "op-b".into(), kind: DeviceKind::Controller, owner: 7 });
                for (v, owner) in owners {
                    let name = if v == 100 { "rover-1" } else { "rover-2" };
                    emit(Event::DeviceSeen { id: v, name: name.into(), kind: DeviceKind::Vehicle, owner });
                }
                emit(Event::Input(InputStatus {
                    live: true, deadman: Some(true), link: "demo input: ok".into(),
                    ..InputStatus::default()
                }));
            }
            _ = &mut ask_at, if !asked => {
                asked = true;
                emit(Event::RequestIncoming(Prompt {
                    vehicle: 100, requester: 7, src_priority: 340,
                    deadline: clock() + Duration::from_secs(10),
                }));
            }
            request = requests.recv() => {
                let Some(CommandRequest { command, reply, .. }) = request else { break };
                let result = match command {
                    Command::Drive { vehicle } | Command::Request { vehicle } => {
                        driving.insert(vehicle);
                        for o in owners.iter_mut().filter(|o| o.0 == vehicle) {
                            emit(Event::OwnerChanged { vehicle, from: o.1, to: 1, reason: command.name().into() });
                            o.1 = 1;
                        }
                        Ok(())
                    }
                    Command::Release { vehicle } => {
                        for o in owners.iter_mut().filter(|o| vehicle.is_none_or(|v| v == o.0) && o.1 == 1) {
                            emit(Event::OwnerChanged { vehicle: o.0, from: 1, to: o.0, reason: "released".into() });
                            o.1 = o.0;
                            driving.remove(&o.0);
                        }
                        Ok(())
                    }
                    Command::Accept { vehicle } | Command::Refuse { vehicle } => {
                        let accepted = matches!(command, Command::Accept { .. });
                        let outcome = if accepted { Outcome::Accepted } else { Outcome::Refused };
                        emit(Event::PromptClosed { vehicle, outcome });
                        Ok(())
                    }
                    Command::Select { vehicle } => {
                        emit(Event::Selected { vehicle: Some(vehicle) });
                        Ok(())
                    }
                    other => Err(format!("the demo does not do {}", other.name())),
                };
                emit(Event::Driving {
                    driving: driving.iter().copied().collect(),
                    holding: vec![], standby: vec![], paused: vec![],
                });
                let _ = reply.send(result);
            }
            _ = tokio::time::sleep(Duration::from_millis(200)) => {
                if console.is_finished() { break; }
            }
        }
    }
    console.await.map_err(std::io::Error::other)?
}
