//! Keys and joystick buttons → [`Command`]s, with the confirmation rule.
//!
//! | key | button ([`InputAction`]) | does |
//! |---|---|---|
//! | ↑ / k, ↓ / j | PreviousVehicle, NextVehicle | select a vehicle |
//! | d | RequestControl | drive the selected vehicle: free → DRIVE, owned by another → REQUEST (confirmed) |
//! | r | – | REQUEST the selected vehicle from its owner (confirmed) |
//! | s | Release | stop driving the selected vehicle (immediate) |
//! | space | – | stop driving every vehicle (immediate) |
//! | f | Finish | FINISH the grant on the selected vehicle (or the first one held; immediate) |
//! | m, 1 / 2 / 3 | Mode(…) | next mode, or manual / assisted / auto (confirmed) |
//! | a | Accept | ACCEPT the open request (the prompt names vehicle and requester) |
//! | x / n / Esc | Refuse | REFUSE the open request |
//! | y / Enter, n / Esc | Accept, Refuse | answer the open confirmation |
//! | q, Ctrl-C | – | quit (the operator releases everything) |
//!
//! The rule: a key that can make a vehicle move under *this* operator's sticks (drive,
//! request, mode) only opens a confirmation naming the target; the command is returned on
//! "yes". Accepting a request is answered on its own prompt, which names the vehicle and the
//! requester. Stopping (release, finish, quit) is never delayed by a question.
//!
//! Two questions never share a "yes": a request that arrives closes an open confirmation, the
//! request prompt takes `a`, not `y` / Enter, and an accept within [`ACCEPT_GUARD`] of the prompt
//! opening is ignored, so a press meant for something else cannot give a vehicle away.

use crate::command::Command;
use crate::model::{Confirmation, ConsoleState, MyRole};
use crossterm::event::{KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
use rove_core::MonoTime;
use rove_core::adapter::InputAction;
use rove_core::msg::{DeviceId, Mode};
use std::time::Duration;

/// Accept presses this soon after a request prompt opened are ignored: about a human reaction
/// time, so a press already on its way when the prompt appeared does not accept it. Longer
/// would make a deliberate quick accept feel broken.
pub const ACCEPT_GUARD: Duration = Duration::from_millis(500);

/// Handles a terminal key at `now`; returns the command to send to the operator, if any.
pub fn on_key(state: &mut ConsoleState, key: KeyEvent, now: MonoTime) -> Option<Command> {
    if key.kind == KeyEventKind::Release {
        return None;
    }
    let ctrl = key.modifiers.contains(KeyModifiers::CONTROL);
    match key.code {
        KeyCode::Char('c') if ctrl => {
            state.quit = true;
            None
        }
        KeyCode::Char('q') => {
            state.quit = true;
            None
        }
        KeyCode::Char('y') | KeyCode::Enter if state.confirm.is_some() => confirm(state, now),
        KeyCode::Char('n') | KeyCode::Esc if state.confirm.is_some() => {
            state.confirm = None;
            None
        }
        KeyCode::Char('a') => accept(state, now),
        KeyCode::Char('x') | KeyCode::Char('n') | KeyCode::Esc => refuse(state),
        KeyCode::Up | KeyCode::Char('k') => select(state, -1),
        KeyCode::Down | KeyCode::Char('j') => select(state, 1),
        KeyCode::Char('d') | KeyCode::Enter => drive(state, now),
        KeyCode::Char('r') => request(state, now),
        KeyCode::Char('s') => release(state),
        KeyCode::Char(' ') => Some(Command::Release { vehicle: None }),
        KeyCode::Char('f') => finish(state),
        KeyCode::Char('m') => {
            let next = match state.input.mode {
                Mode::Manual => Mode::Assisted,
                Mode::Assisted => Mode::Auto,
                Mode::Auto => Mode::Manual,
            };
            mode(state, next, now)
        }
        KeyCode::Char('1') => mode(state, Mode::Manual, now),
        KeyCode::Char('2') => mode(state, Mode::Assisted, now),
        KeyCode::Char('3') => mode(state, Mode::Auto, now),
        _ => None,
    }
}

/// Handles a joystick button (from the input config) at `now`, like the matching key.
pub fn on_action(state: &mut ConsoleState, action: InputAction, now: MonoTime) -> Option<Command> {
    match action {
        InputAction::Mode(m) => mode(state, m, now),
        InputAction::RequestControl => drive(state, now),
        // A button has no separate "yes": Accept answers the confirmation first (opened by this
        // operator's own last press), else the request prompt.
        InputAction::Accept if state.confirm.is_some() => confirm(state, now),
        InputAction::Accept => accept(state, now),
        InputAction::Refuse if state.confirm.is_some() => {
            state.confirm = None;
            None
        }
        InputAction::Refuse => refuse(state),
        InputAction::Finish => finish(state),
        InputAction::Release => release(state),
        InputAction::NextVehicle => select(state, 1),
        InputAction::PreviousVehicle => select(state, -1),
    }
}

fn confirm(state: &mut ConsoleState, now: MonoTime) -> Option<Command> {
    let c = state.confirm.take()?;
    // `apply` closes stale confirmations on every event; this covers a key with no event since.
    (now.saturating_since(c.opened) < crate::model::CONFIRM_TIMEOUT).then_some(c.command)
}

fn ask(state: &mut ConsoleState, command: Command, question: String, now: MonoTime) {
    state.confirm = Some(Confirmation {
        command,
        question,
        opened: now,
    });
}

fn accept(state: &mut ConsoleState, now: MonoTime) -> Option<Command> {
    let req = *state.prompt()?;
    if now.saturating_since(req.opened) < ACCEPT_GUARD {
        return None;
    }
    Some(Command::Accept {
        vehicle: req.vehicle,
    })
}

fn refuse(state: &mut ConsoleState) -> Option<Command> {
    let req = state.prompt()?;
    Some(Command::Refuse {
        vehicle: req.vehicle,
    })
}

fn select(state: &mut ConsoleState, step: isize) -> Option<Command> {
    let ids: Vec<DeviceId> = state.vehicles().map(|d| d.id).collect();
    let n = ids.len();
    if n == 0 {
        return None;
    }
    let at = state
        .selected
        .and_then(|s| ids.iter().position(|&v| v == s));
    let index = match at {
        None => 0,
        Some(i) => (i as isize + step).rem_euclid(n as isize) as usize,
    };
    let vehicle = *ids.get(index)?;
    state.selected = Some(vehicle);
    Some(Command::Select { vehicle })
}

/// Drive the selected vehicle: at once if free, else by asking its owner.
fn drive(state: &mut ConsoleState, now: MonoTime) -> Option<Command> {
    let vehicle = state.selected?;
    let owner = state
        .devices
        .get(&vehicle)
        .and_then(|d| d.vehicle.as_ref())
        .map_or(vehicle, |v| v.owner);
    if matches!(
        state.mine.get(&vehicle),
        Some(MyRole::Driving | MyRole::Holding)
    ) {
        return None;
    }
    if owner == vehicle || owner == state.identity.id {
        let question = format!("Drive {}?", state.label(vehicle));
        ask(state, Command::Drive { vehicle }, question, now);
        None
    } else {
        request(state, now)
    }
}

fn request(state: &mut ConsoleState, now: MonoTime) -> Option<Command> {
    let vehicle = state.selected?;
    let owner = state
        .devices
        .get(&vehicle)
        .and_then(|d| d.vehicle.as_ref())
        .map_or(vehicle, |v| v.owner);
    let question = format!(
        "Ask {} for {}? You drive it if they accept.",
        state.owner_label(vehicle, owner),
        state.label(vehicle)
    );
    ask(state, Command::Request { vehicle }, question, now);
    None
}

fn release(state: &mut ConsoleState) -> Option<Command> {
    let vehicle = state.selected?;
    Some(Command::Release {
        vehicle: Some(vehicle),
    })
}

fn finish(state: &mut ConsoleState) -> Option<Command> {
    let held: Vec<DeviceId> = state
        .mine
        .iter()
        .filter(|(_, r)| **r == MyRole::Holding)
        .map(|(v, _)| *v)
        .collect();
    let vehicle = state
        .selected
        .filter(|s| held.contains(s))
        .or_else(|| held.first().copied())?;
    Some(Command::Finish { vehicle })
}

fn mode(state: &mut ConsoleState, mode: Mode, now: MonoTime) -> Option<Command> {
    let driven: Vec<String> = state
        .mine
        .iter()
        .filter(|(_, r)| matches!(r, MyRole::Driving | MyRole::Holding))
        .map(|(v, _)| state.label(*v))
        .collect();
    let name = crate::view::mode_name(mode).to_uppercase();
    let question = if driven.is_empty() {
        format!("Set mode {name}? (you drive nothing now)")
    } else {
        format!("Switch {} to {name}?", driven.join(", "))
    };
    ask(
        state,
        Command::Mode {
            vehicle: None,
            mode,
        },
        question,
        now,
    );
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::tests::{me, ms, seen};
    use crate::model::{DeviceKind, Event};
    use rove_core::handover::Prompt;

    fn key(c: char) -> KeyEvent {
        KeyEvent::from(KeyCode::Char(c))
    }

    fn fleet() -> ConsoleState {
        let mut s = ConsoleState::new(me(), Duration::from_secs(3));
        s.apply(ms(0), seen(100, "rover-1", DeviceKind::Vehicle, 100));
        s.apply(ms(0), seen(101, "rover-2", DeviceKind::Vehicle, 7));
        s.apply(ms(0), seen(7, "op-b", DeviceKind::Controller, 7));
        s
    }

    #[test]
    fn drive_needs_a_confirmation_naming_the_vehicle() {
        let mut s = fleet();
        assert_eq!(on_key(&mut s, key('d'), ms(10)), None);
        let question = s.confirm.as_ref().map(|c| c.question.clone());
        assert_eq!(question.as_deref(), Some("Drive rover-1 (100)?"));
        assert_eq!(
            on_key(&mut s, key('y'), ms(20)),
            Some(Command::Drive { vehicle: 100 })
        );
        assert_eq!(s.confirm, None);
    }

    #[test]
    fn no_and_escape_cancel_and_enter_confirms() {
        let mut s = fleet();
        on_key(&mut s, key('d'), ms(10));
        assert_eq!(on_key(&mut s, key('n'), ms(11)), None);
        assert_eq!(s.confirm, None);
        on_key(&mut s, key('d'), ms(12));
        assert_eq!(on_key(&mut s, KeyEvent::from(KeyCode::Esc), ms(13)), None);
        assert_eq!(s.confirm, None);
        on_key(&mut s, key('d'), ms(14));
        assert_eq!(
            on_key(&mut s, KeyEvent::from(KeyCode::Enter), ms(15)),
            Some(Command::Drive { vehicle: 100 })
        );
    }

    #[test]
    fn a_stale_confirmation_does_nothing() {
        let mut s = fleet();
        on_key(&mut s, key('d'), ms(0));
        let late = ms(0) + crate::model::CONFIRM_TIMEOUT;
        assert_eq!(on_key(&mut s, key('y'), late), None);
    }

    #[test]
    fn drive_on_an_owned_vehicle_asks_its_owner() {
        let mut s = fleet();
        assert_eq!(
            on_key(&mut s, KeyEvent::from(KeyCode::Down), ms(1)),
            Some(Command::Select { vehicle: 101 })
        );
        on_key(&mut s, key('d'), ms(2));
        let question = s.confirm.as_ref().map(|c| c.question.clone());
        assert_eq!(
            question.as_deref(),
            Some("Ask op-b (7) for rover-2 (101)? You drive it if they accept.")
        );
        assert_eq!(
            on_key(&mut s, key('y'), ms(3)),
            Some(Command::Request { vehicle: 101 })
        );
    }

    #[test]
    fn selection_wraps_both_ways() {
        let mut s = fleet();
        assert_eq!(s.selected, Some(100));
        on_key(&mut s, key('k'), ms(1));
        assert_eq!(s.selected, Some(101));
        on_key(&mut s, key('j'), ms(1));
        assert_eq!(s.selected, Some(100));
    }

    #[test]
    fn stopping_is_immediate() {
        let mut s = fleet();
        assert_eq!(
            on_key(&mut s, key('s'), ms(1)),
            Some(Command::Release { vehicle: Some(100) })
        );
        assert_eq!(
            on_key(&mut s, key(' '), ms(1)),
            Some(Command::Release { vehicle: None })
        );
        assert_eq!(on_key(&mut s, key('f'), ms(1)), None, "no grant held");
        s.apply(
            ms(2),
            Event::Driving {
                driving: vec![],
                holding: vec![101],
                standby: vec![],
                paused: vec![],
            },
        );
        assert_eq!(
            on_key(&mut s, key('f'), ms(3)),
            Some(Command::Finish { vehicle: 101 })
        );
        assert!(!s.quit);
        on_key(
            &mut s,
            KeyEvent::new(KeyCode::Char('c'), KeyModifiers::CONTROL),
            ms(4),
        );
        assert!(s.quit);
    }

    #[test]
    fn mode_change_is_confirmed_and_names_the_driven_vehicles() {
        let mut s = fleet();
        s.apply(
            ms(1),
            Event::Driving {
                driving: vec![100],
                holding: vec![],
                standby: vec![],
                paused: vec![],
            },
        );
        on_key(&mut s, key('2'), ms(2));
        let question = s.confirm.as_ref().map(|c| c.question.clone());
        assert_eq!(
            question.as_deref(),
            Some("Switch rover-1 (100) to ASSISTED?")
        );
        assert_eq!(
            on_key(&mut s, key('y'), ms(3)),
            Some(Command::Mode {
                vehicle: None,
                mode: Mode::Assisted
            })
        );
    }

    fn incoming(s: &mut ConsoleState, at: u64) {
        s.apply(
            ms(at),
            Event::RequestIncoming(Prompt {
                vehicle: 100,
                requester: 7,
                src_priority: 340,
                deadline: ms(at + 10_000),
            }),
        );
    }

    #[test]
    fn request_prompt_takes_a_and_x_not_y_and_guards_early_accepts() {
        let mut s = fleet();
        incoming(&mut s, 1_000);
        assert_eq!(on_key(&mut s, key('y'), ms(2_000)), None);
        assert_eq!(
            on_key(&mut s, key('a'), ms(1_100)),
            None,
            "inside the guard"
        );
        assert_eq!(
            on_key(&mut s, key('a'), ms(1_600)),
            Some(Command::Accept { vehicle: 100 })
        );
        assert_eq!(
            on_key(&mut s, key('x'), ms(1_700)),
            Some(Command::Refuse { vehicle: 100 })
        );
    }

    #[test]
    fn joystick_buttons_follow_the_same_rules() {
        let mut s = fleet();
        assert_eq!(on_action(&mut s, InputAction::RequestControl, ms(1)), None);
        assert!(s.confirm.is_some());
        assert_eq!(on_action(&mut s, InputAction::Refuse, ms(2)), None);
        assert_eq!(s.confirm, None, "refuse cancels the confirmation");
        on_action(&mut s, InputAction::RequestControl, ms(3));
        assert_eq!(
            on_action(&mut s, InputAction::Accept, ms(4)),
            Some(Command::Drive { vehicle: 100 })
        );
        // A request arriving after a press closes that press's confirmation: the next
        // Accept press cannot land on the request inside the guard.
        on_action(&mut s, InputAction::Mode(Mode::Auto), ms(5));
        incoming(&mut s, 6);
        assert_eq!(s.confirm, None);
        assert_eq!(on_action(&mut s, InputAction::Accept, ms(100)), None);
        assert_eq!(
            on_action(&mut s, InputAction::Refuse, ms(101)),
            Some(Command::Refuse { vehicle: 100 })
        );
        assert_eq!(
            on_action(&mut s, InputAction::NextVehicle, ms(102)),
            Some(Command::Select { vehicle: 101 })
        );
    }
}
