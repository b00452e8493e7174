//! Drawing: the console screen from a [`ConsoleState`], and the device table it shares with
//! `rove status --watch`.
//!
//! Pure functions of their arguments: the time shown (ages, countdowns) comes from `now`, so a
//! test renders into ratatui's `TestBackend` and reads the text back with [`buffer_text`].

use crate::model::{ConsoleState, DeviceKind, IncomingRequest, Logged};
use crate::standing::Standing;
use ratatui::Frame;
use ratatui::buffer::Buffer;
use ratatui::layout::{Constraint, Layout, Rect};
use ratatui::style::{Color, Modifier, Style};
use ratatui::text::{Line, Span};
use ratatui::widgets::{Block, Cell, Clear, Paragraph, Row, Table, Wrap};
use rove_core::MonoTime;
use rove_core::msg::{DeviceId, Mode, VehicleHealth};
use std::time::Duration;

/// Lower-case mode name, as the API and the screen spell it.
pub fn mode_name(mode: Mode) -> &'static str {
    match mode {
        Mode::Manual => "manual",
        Mode::Assisted => "assisted",
        Mode::Auto => "auto",
    }
}

/// One row of the device table: a plain struct that both the console ([`rows`]) and
/// `rove status` fill in.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeviceRow {
    /// Device id.
    pub id: DeviceId,
    /// Name.
    pub name: String,
    /// Vehicle or controller.
    pub kind: DeviceKind,
    /// Online.
    pub online: bool,
    /// Time since its last announcement.
    pub age: Duration,
    /// Vehicles: where it stands (for this operator; for `rove status`, a bystander), with its
    /// words ([`Standing::text`]).
    pub standing: Option<(Standing, String)>,
    /// Mode, if known.
    pub mode: Option<Mode>,
    /// Vehicles: what its device says (battery, autopilot), once a status report said.
    pub health: Option<VehicleHealth>,
    /// Output-link health, if known.
    pub link: Option<String>,
    /// The selected vehicle (marked `>`).
    pub selected: bool,
}

impl DeviceKind {
    /// Parses `"vehicle"` / `"controller"` (as `rove status` spells them).
    pub fn from_name(name: &str) -> Option<DeviceKind> {
        match name {
            "vehicle" => Some(DeviceKind::Vehicle),
            "controller" => Some(DeviceKind::Controller),
            _ => None,
        }
    }
}

/// The console's device rows at `now`.
pub fn rows(state: &ConsoleState, now: MonoTime) -> Vec<DeviceRow> {
    state
        .devices
        .values()
        .map(|d| {
            let standing = state.standing_text(d.id);
            DeviceRow {
                id: d.id,
                name: d.name.clone(),
                kind: d.kind,
                online: d.online,
                age: now.saturating_since(d.last_seen),
                standing,
                mode: d.vehicle.as_ref().and_then(|v| v.mode),
                health: (d.vehicle.as_ref())
                    .filter(|v| v.link.is_some())
                    .map(|v| v.health.clone()),
                link: d.vehicle.as_ref().and_then(|v| v.link.clone()),
                selected: state.selected == Some(d.id),
            }
        })
        .collect()
}

fn age_text(age: Duration) -> String {
    let s = age.as_secs_f64();
    if s < 10.0 {
        format!("{s:.1}s")
    } else if s < 120.0 {
        format!("{}s", age.as_secs())
    } else {
        format!("{}m", age.as_secs() / 60)
    }
}

/// The battery as the consoles show it, e.g. `"11.4V 62%"`; `None` when the vehicle's device
/// does not know it. (Whether it is low is [`VehicleHealth::battery_low`], shown beside it.)
pub fn battery_text(health: &VehicleHealth) -> Option<String> {
    let volts =
        (health.battery_mv >= 0).then(|| format!("{:.1}V", f64::from(health.battery_mv) / 1000.0));
    let pct = (health.battery_pct >= 0).then(|| format!("{}%", health.battery_pct));
    let known: Vec<String> = [volts, pct].into_iter().flatten().collect();
    (!known.is_empty()).then(|| known.join(" "))
}

/// The autopilot as the consoles show it, e.g. `"HOLD armed 0.4s"`; `None` without one.
pub fn autopilot_text(health: &VehicleHealth) -> Option<String> {
    if health.autopilot_mode.is_empty() {
        return None;
    }
    let armed = if health.armed { "armed" } else { "disarmed" };
    let age = u64::try_from(health.link_age_ms)
        .map(|ms| format!(" {}", age_text(Duration::from_millis(ms))))
        .unwrap_or_default();
    Some(format!("{} {armed}{age}", health.autopilot_mode))
}

fn you_drive_style() -> Style {
    Style::new()
        .fg(Color::Black)
        .bg(Color::Green)
        .add_modifier(Modifier::BOLD)
}

/// How a standing is drawn: driving highlighted, safe outputs and lost places in yellow.
fn standing_style(standing: &Standing) -> Style {
    match standing {
        Standing::Driving { .. } => you_drive_style(),
        Standing::Offline => Style::new().fg(Color::Red),
        Standing::StandingBy { .. } => Style::new(),
        _ => Style::new().fg(Color::Yellow),
    }
}

/// The device table: one row per device, vehicles with where they stand (this operator's
/// vehicles highlighted "you drive"), battery and autopilot. Shared by the console and
/// `rove status`.
pub fn device_table(rows: &[DeviceRow]) -> Table<'static> {
    let header = Row::new([
        "",
        "ID",
        "NAME",
        "TYPE",
        "STATE",
        "SEEN",
        "STANDING",
        "MODE",
        "BATTERY",
        "AUTOPILOT",
        "LINK",
    ])
    .style(Style::new().add_modifier(Modifier::BOLD));
    let body = rows.iter().map(|r| {
        let state = if r.online {
            Span::styled("online", Style::new().fg(Color::Green))
        } else {
            Span::styled("offline", Style::new().fg(Color::Red))
        };
        let standing = match &r.standing {
            None => Span::raw(""),
            Some((s, text)) => Span::styled(text.clone(), standing_style(s)),
        };
        let battery = match r
            .health
            .as_ref()
            .and_then(|h| battery_text(h).map(|t| (t, h)))
        {
            None => Span::raw(""),
            Some((text, h)) if h.battery_low => Span::styled(
                format!("LOW {text}"),
                Style::new().fg(Color::Red).add_modifier(Modifier::BOLD),
            ),
            Some((text, _)) => Span::raw(text),
        };
        let autopilot = r
            .health
            .as_ref()
            .and_then(autopilot_text)
            .unwrap_or_default();
        let row = Row::new([
            Cell::from(if r.selected { ">" } else { "" }),
            Cell::from(r.id.to_string()),
            Cell::from(r.name.clone()),
            Cell::from(r.kind.as_str()),
            Cell::from(state),
            Cell::from(age_text(r.age)),
            Cell::from(standing),
            Cell::from(r.mode.map(mode_name).unwrap_or("")),
            Cell::from(battery),
            Cell::from(autopilot),
            Cell::from(r.link.clone().unwrap_or_default()),
        ]);
        if r.selected {
            row.style(Style::new().add_modifier(Modifier::BOLD))
        } else {
            row
        }
    });
    Table::new(
        body,
        [
            Constraint::Length(1),
            Constraint::Length(5),
            Constraint::Length(12),
            Constraint::Length(10),
            Constraint::Length(7),
            Constraint::Length(5),
            Constraint::Length(40),
            Constraint::Length(8),
            Constraint::Length(12),
            Constraint::Length(17),
            Constraint::Min(4),
        ],
    )
    .header(header)
}

/// `rove status --watch`: the device table alone, full screen, under `title`.
pub fn render_status(frame: &mut Frame, title: &str, rows: &[DeviceRow]) {
    let table = device_table(rows).block(Block::bordered().title(title.to_string()));
    frame.render_widget(table, frame.area());
}

/// The device table as plain text, `width` columns wide, one line per row (no borders): for
/// `rove status` on a terminal that is not interactive.
pub fn status_text(rows: &[DeviceRow], width: u16) -> String {
    let height = u16::try_from(rows.len() + 1).unwrap_or(u16::MAX);
    let area = Rect::new(0, 0, width, height);
    let mut buf = Buffer::empty(area);
    ratatui::widgets::Widget::render(device_table(rows), area, &mut buf);
    buffer_text(&buf)
}

/// A buffer's text, one line per row, trailing spaces removed.
pub fn buffer_text(buf: &Buffer) -> String {
    let area = buf.area;
    let mut out = String::new();
    for y in area.top()..area.bottom() {
        let mut line = String::new();
        for x in area.left()..area.right() {
            if let Some(cell) = buf.cell((x, y)) {
                line.push_str(cell.symbol());
            }
        }
        out.push_str(line.trim_end());
        out.push('\n');
    }
    out
}

/// Whole seconds left until `deadline`, rounded up (a prompt shows "1 s" until it closes).
pub fn seconds_left(deadline: MonoTime, now: MonoTime) -> u64 {
    deadline.saturating_since(now).as_millis().div_ceil(1000) as u64
}

/// Draws the console at `now`.
pub fn render(frame: &mut Frame, state: &ConsoleState, now: MonoTime) {
    let [header, table, bottom, footer] = Layout::vertical([
        Constraint::Length(4),
        Constraint::Min(4),
        Constraint::Length(9),
        Constraint::Length(1),
    ])
    .areas(frame.area());
    frame.render_widget(header_widget(state, now), header);
    let rows = rows(state, now);
    frame.render_widget(
        device_table(&rows).block(Block::bordered().title(" devices ")),
        table,
    );
    let [input, log] =
        Layout::horizontal([Constraint::Length(34), Constraint::Min(20)]).areas(bottom);
    frame.render_widget(input_widget(state), input);
    frame.render_widget(log_widget(state, log.height.saturating_sub(2)), log);
    frame.render_widget(
        Paragraph::new(
            "↑↓ select  d drive  r request  s stop  space stop all  f finish  m/1-3 mode  q quit",
        )
        .style(Style::new().fg(Color::DarkGray)),
        footer,
    );
    if let Some(req) = state.prompt() {
        request_prompt(frame, state, req, now);
    }
    if let Some(c) = &state.confirm {
        let area = centred(frame.area(), 64, 5);
        frame.render_widget(Clear, area);
        let text = vec![
            Line::from(Span::styled(
                c.question.clone(),
                Style::new().add_modifier(Modifier::BOLD),
            )),
            Line::from(""),
            Line::from("y / Enter = yes    n / Esc = no"),
        ];
        frame.render_widget(
            Paragraph::new(text)
                .wrap(Wrap { trim: true })
                .block(Block::bordered().title(" confirm ")),
            area,
        );
    }
}

fn header_widget(state: &ConsoleState, now: MonoTime) -> Paragraph<'static> {
    let id = &state.identity;
    let first = Line::from(vec![
        Span::styled(
            format!("{} (id {})", id.name, id.id),
            Style::new().add_modifier(Modifier::BOLD),
        ),
        Span::raw(format!(
            "  level {:?} · {:?} · strength {}",
            id.level, id.class, id.strength
        )),
    ]);
    // What this operator drives, where the selected vehicle stands, and every low battery:
    // from the same standings as the rows.
    let driving: Vec<String> = (state.vehicles())
        .filter(|d| matches!(state.standing(d.id), Some(Standing::Driving { .. })))
        .map(|d| state.label(d.id))
        .collect();
    let driving = match driving.is_empty() {
        true => "nothing".to_string(),
        false => driving.join(", "),
    };
    let selected = match state.selected {
        None => Span::raw("none"),
        Some(v) => match state.standing_text(v) {
            Some((standing, text)) => Span::styled(
                format!("{}: {text}", state.label(v)),
                standing_style(&standing),
            ),
            None => Span::raw(state.label(v)),
        },
    };
    let mut second = vec![
        Span::raw("you drive: "),
        Span::raw(driving),
        Span::raw("   selected: "),
        selected,
    ];
    for d in state.vehicles().filter(|d| d.online) {
        if let Some(v) = d.vehicle.as_ref().filter(|v| v.health.battery_low) {
            second.push(Span::styled(
                format!(
                    "   LOW BATTERY {}: {}",
                    state.label(d.id),
                    battery_text(&v.health).unwrap_or_default()
                ),
                Style::new().fg(Color::Red).add_modifier(Modifier::BOLD),
            ));
        }
    }
    for (&vehicle, req) in &state.outgoing {
        second.push(Span::styled(
            format!(
                "   asking {} for {} ({}s)",
                state.label(req.owner),
                state.label(vehicle),
                now.saturating_since(req.since).as_secs()
            ),
            Style::new().fg(Color::Yellow),
        ));
    }
    Paragraph::new(vec![first, Line::from(second)])
        .block(Block::bordered().title(" rove operator "))
}

fn axis_bar(value: i16) -> String {
    // 10 cells: five for each direction, filled from the centre.
    let filled = (i32::from(value).abs() * 5).div_euclid(32767).clamp(0, 5) as usize;
    let (left, right) = if value < 0 {
        (
            format!("{}{}", " ".repeat(5 - filled), "█".repeat(filled)),
            " ".repeat(5),
        )
    } else {
        (
            " ".repeat(5),
            format!("{}{}", "█".repeat(filled), " ".repeat(5 - filled)),
        )
    };
    format!("[{left}|{right}]")
}

fn input_widget(state: &ConsoleState) -> Paragraph<'static> {
    let i = &state.input;
    let axis = |name: &str, v: i16| Line::from(format!("{name:<9}{v:>+7} {}", axis_bar(v)));
    let deadman = match i.deadman {
        None => Span::raw("none"),
        Some(true) => Span::styled("HELD", Style::new().fg(Color::Green)),
        Some(false) => Span::styled("RELEASED", Style::new().fg(Color::Red)),
    };
    let live = if i.live {
        Span::styled("LIVE", Style::new().fg(Color::Green))
    } else {
        Span::styled("not live", Style::new().fg(Color::Red))
    };
    Paragraph::new(vec![
        Line::from(vec![
            Span::raw("mode     "),
            Span::raw(mode_name(i.mode).to_uppercase()),
            Span::raw("  "),
            live,
        ]),
        axis("throttle", i.movement.throttle),
        axis("roll", i.movement.roll),
        axis("pitch", i.movement.pitch),
        axis("yaw", i.movement.yaw),
        Line::from(vec![Span::raw("deadman  "), deadman]),
        Line::from(i.link.clone()),
    ])
    .block(Block::bordered().title(" input "))
}

fn log_widget(state: &ConsoleState, lines: u16) -> Paragraph<'static> {
    let skip = state.log.len().saturating_sub(usize::from(lines));
    let text: Vec<Line> = state
        .log
        .iter()
        .skip(skip)
        .map(|e| {
            let secs = e.at.as_nanos() as f64 / 1e9;
            let body = match &e.what {
                Logged::Owner {
                    vehicle,
                    from,
                    to,
                    reason,
                } => format!(
                    "{}: {} → {} ({reason})",
                    state.label(*vehicle),
                    state.owner_label(*vehicle, *from),
                    state.owner_label(*vehicle, *to)
                ),
                Logged::Note(text) => text.clone(),
            };
            Line::from(format!("{secs:>8.1}s  {body}"))
        })
        .collect();
    Paragraph::new(text).block(Block::bordered().title(" log "))
}

fn request_prompt(frame: &mut Frame, state: &ConsoleState, req: &IncomingRequest, now: MonoTime) {
    let area = centred(frame.area(), 64, 8);
    frame.render_widget(Clear, area);
    let secs = seconds_left(req.deadline, now);
    let text = vec![
        Line::from(Span::styled(
            format!(
                "{} asks for {}",
                state.label(req.from),
                state.label(req.vehicle)
            ),
            Style::new().add_modifier(Modifier::BOLD),
        )),
        Line::from(format!(
            "their priority {}, your strength {}",
            req.src_priority, state.identity.strength
        )),
        Line::from(""),
        Line::from("a = accept (they drive it)    x / Esc = refuse"),
        Line::from(Span::styled(
            format!("refused automatically in {secs} s"),
            Style::new().fg(Color::Yellow),
        )),
    ];
    frame.render_widget(
        Paragraph::new(text).block(
            Block::bordered()
                .title(" CONTROL REQUEST ")
                .border_style(Style::new().fg(Color::Yellow)),
        ),
        area,
    );
}

fn centred(area: Rect, width: u16, height: u16) -> Rect {
    let width = width.min(area.width);
    let height = height.min(area.height);
    Rect::new(
        area.x + (area.width - width) / 2,
        area.y + (area.height - height) / 2,
        width,
        height,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::tests::{me, ms, seen};
    use crate::model::{Event, InputStatus};
    use ratatui::Terminal;
    use ratatui::backend::TestBackend;
    use rove_core::handover::Prompt;
    use rove_core::msg::MovementCommand;

    /// Wide enough for every column at its width (a narrower terminal shrinks them).
    const WIDTH: u16 = 150;

    fn screen(state: &ConsoleState, now: MonoTime) -> String {
        let mut terminal = match Terminal::new(TestBackend::new(WIDTH, 30)) {
            Ok(t) => t,
            Err(e) => panic!("test backend: {e}"),
        };
        if let Err(e) = terminal.draw(|f| render(f, state, now)) {
            panic!("draw: {e}");
        }
        buffer_text(terminal.backend().buffer())
    }

    fn line_with<'a>(text: &'a str, needle: &str) -> &'a str {
        text.lines()
            .find(|l| l.contains(needle))
            .unwrap_or_else(|| panic!("no line with {needle:?} in\n{text}"))
    }

    /// The device-table row of `name`.
    fn row<'a>(text: &'a str, name: &str) -> &'a str {
        text.lines()
            .find(|l| {
                l.contains(&format!(" {name} "))
                    && (l.contains(" vehicle ") || l.contains(" controller "))
            })
            .unwrap_or_else(|| panic!("no row for {name:?} in\n{text}"))
    }

    /// A scripted session: two vehicles, another operator, we drive one.
    fn script() -> ConsoleState {
        let mut s = ConsoleState::new(me(), Duration::from_secs(3));
        s.apply(ms(0), seen(1, "laptop-1", DeviceKind::Controller, 1));
        s.apply(ms(0), seen(100, "rover-1", DeviceKind::Vehicle, 100));
        s.apply(ms(0), seen(101, "rover-2", DeviceKind::Vehicle, 7));
        s.apply(ms(0), seen(7, "op-b", DeviceKind::Controller, 7));
        s.apply(
            ms(500),
            Event::Driving {
                driving: vec![100],
                holding: vec![],
                standby: vec![],
                paused: vec![],
            },
        );
        s.apply(
            ms(600),
            Event::OwnerChanged {
                vehicle: 100,
                from: 100,
                to: 1,
                reason: "you started driving".into(),
            },
        );
        s.apply(
            ms(700),
            Event::Input(InputStatus {
                movement: MovementCommand {
                    throttle: 16384,
                    roll: -32767,
                    pitch: 0,
                    yaw: 0,
                },
                mode: Mode::Manual,
                deadman: Some(true),
                live: true,
                link: "evdev gamepad: ok".into(),
            }),
        );
        s
    }

    #[test]
    fn shows_identity_devices_owner_marks_input_and_log() {
        let s = script();
        let text = screen(&s, ms(1_000));
        assert!(text.contains("laptop-1 (id 1)"), "{text}");
        assert!(
            text.contains("level Mobile · Laptop · strength 320"),
            "{text}"
        );
        assert!(text.contains("you drive: rover-1 (100)"), "{text}");
        let rover1 = row(&text, "rover-1");
        assert!(rover1.contains("> 100"), "selected mark: {rover1}");
        assert!(rover1.contains("vehicle"), "{rover1}");
        assert!(rover1.contains("online"), "{rover1}");
        assert!(rover1.contains("YOU DRIVE"), "{rover1}");
        let rover2 = row(&text, "rover-2");
        assert!(rover2.contains("driven by op-b (7)"), "{rover2}");
        assert!(!rover2.contains("YOU DRIVE"), "{rover2}");
        let op = row(&text, "op-b");
        assert!(op.contains("controller"), "{op}");
        assert!(line_with(&text, "throttle").contains("+16384 [     |██   ]"));
        assert!(line_with(&text, "roll  ").contains("-32767 [█████|     ]"));
        assert!(line_with(&text, "deadman").contains("HELD"));
        assert!(text.contains("evdev gamepad: ok"));
        assert!(
            line_with(&text, "you started driving")
                .contains("0.6s  rover-1 (100): failsafe → you (1) (you started driving)"),
            "{text}"
        );
    }

    #[test]
    fn the_you_drive_mark_is_highlighted() {
        let s = script();
        let mut terminal = match Terminal::new(TestBackend::new(WIDTH, 30)) {
            Ok(t) => t,
            Err(e) => panic!("{e}"),
        };
        if let Err(e) = terminal.draw(|f| render(f, &s, ms(1_000))) {
            panic!("{e}");
        }
        let buf = terminal.backend().buffer();
        let text = buffer_text(buf);
        let (y, line) = text
            .lines()
            .enumerate()
            .find(|(_, l)| l.contains("YOU DRIVE"))
            .unwrap_or_else(|| panic!("no YOU DRIVE in\n{text}"));
        let x = line.find("YOU DRIVE").map(|b| line[..b].chars().count());
        let cell = x.and_then(|x| buf.cell((x as u16, y as u16)));
        assert_eq!(cell.map(|c| c.bg), Some(Color::Green));
    }

    #[test]
    fn devices_go_offline_as_time_passes() {
        let mut s = script();
        s.apply(ms(5_000), Event::Tick);
        let text = screen(&s, ms(5_000));
        assert!(row(&text, "rover-2").contains("offline"), "{text}");
        assert!(row(&text, "rover-2").contains("5.0s"), "{text}");
    }

    #[test]
    fn request_prompt_counts_down_to_the_consent_deadline() {
        let mut s = script();
        s.apply(
            ms(1_000),
            Event::RequestIncoming(Prompt {
                vehicle: 100,
                requester: 7,
                src_priority: 340,
                deadline: ms(11_000),
            }),
        );
        let text = screen(&s, ms(1_000));
        assert!(text.contains("CONTROL REQUEST"), "{text}");
        assert!(text.contains("op-b (7) asks for rover-1 (100)"), "{text}");
        assert!(
            text.contains("their priority 340, your strength 320"),
            "{text}"
        );
        assert!(text.contains("refused automatically in 10 s"), "{text}");
        s.apply(ms(3_500), Event::Tick);
        let text = screen(&s, ms(3_500));
        assert!(text.contains("refused automatically in 8 s"), "{text}");
        let text = screen(&s, ms(10_999));
        assert!(text.contains("refused automatically in 1 s"), "{text}");
        let text = screen(&s, ms(12_000));
        assert!(text.contains("refused automatically in 0 s"), "{text}");
        s.apply(
            ms(11_000),
            Event::PromptClosed {
                vehicle: 100,
                outcome: crate::model::Outcome::TimedOut,
            },
        );
        let text = screen(&s, ms(11_000));
        assert!(!text.contains("CONTROL REQUEST"), "{text}");
        assert!(
            text.contains("request from op-b (7) for rover-1 (100): timed out"),
            "{text}"
        );
    }

    #[test]
    fn confirmation_prompt_names_the_target() {
        let mut s = script();
        let key = crossterm::event::KeyEvent::from(crossterm::event::KeyCode::Down);
        crate::keys::on_key(&mut s, key, ms(1_000));
        let key = crossterm::event::KeyEvent::from(crossterm::event::KeyCode::Char('d'));
        crate::keys::on_key(&mut s, key, ms(1_000));
        let text = screen(&s, ms(1_000));
        assert!(text.contains(" confirm "), "{text}");
        assert!(
            text.contains("Ask op-b (7) for rover-2 (101)? You drive it if they accept."),
            "{text}"
        );
        assert!(text.contains("y / Enter = yes    n / Esc = no"), "{text}");
        assert!(row(&text, "rover-2").contains("> 101"), "{text}");
    }

    #[test]
    fn standby_grant_and_outranked_marks() {
        let mut s = script();
        s.apply(
            ms(800),
            Event::Driving {
                driving: vec![101],
                holding: vec![],
                standby: vec![100],
                paused: vec![],
            },
        );
        s.apply(
            ms(900),
            Event::OwnerChanged {
                vehicle: 100,
                from: 1,
                to: 7,
                reason: "you accepted op-b's request".into(),
            },
        );
        let text = screen(&s, ms(1_000));
        assert!(
            row(&text, "rover-1").contains("yielded to op-b (7)"),
            "{text}"
        );
        assert!(
            row(&text, "rover-2").contains("outranked by op-b (7)"),
            "{text}"
        );
        s.apply(
            ms(950),
            Event::Driving {
                driving: vec![],
                holding: vec![101],
                standby: vec![],
                paused: vec![],
            },
        );
        s.apply(ms(960), seen(101, "rover-2", DeviceKind::Vehicle, 1));
        let text = screen(&s, ms(1_000));
        assert!(
            row(&text, "rover-2").contains("YOU DRIVE (grant)"),
            "{text}"
        );
        assert!(
            text.contains("rover-2 (101): op-b (7) → you (1) (reported by the vehicle)"),
            "{text}"
        );
    }

    #[test]
    fn status_rows_render_like_rove_status() {
        let vehicle = |id, name: &str, standing: Standing, online, age| DeviceRow {
            id,
            name: name.into(),
            kind: DeviceKind::Vehicle,
            online,
            age,
            standing: Some((standing.clone(), standing.text(|id| id.to_string()))),
            mode: None,
            health: Some(VehicleHealth {
                battery_mv: 10_240,
                battery_pct: 8,
                battery_low: true,
                autopilot_mode: "HOLD".into(),
                armed: true,
                link_age_ms: 400,
                held: false,
            }),
            link: None,
            selected: false,
        };
        let rows = [
            vehicle(
                100,
                "rover-1",
                Standing::Failsafe,
                true,
                Duration::from_millis(300),
            ),
            vehicle(
                101,
                "rover-2",
                Standing::Offline,
                false,
                Duration::from_secs(15),
            ),
            DeviceRow {
                id: 7,
                name: "op-b".into(),
                kind: DeviceKind::Controller,
                online: true,
                age: Duration::from_secs(300),
                standing: None,
                mode: None,
                health: None,
                link: None,
                selected: false,
            },
        ];
        let text = status_text(&rows, WIDTH);
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 4, "{text}");
        assert!(lines[0].contains("ID") && lines[0].contains("STANDING"));
        assert!(lines[1].contains("rover-1") && lines[1].contains("failsafe"));
        assert!(lines[1].contains("0.3s"), "{text}");
        assert!(lines[1].contains("LOW 10.2V 8%"), "{text}");
        assert!(lines[1].contains("HOLD armed 0.4s"), "{text}");
        assert!(lines[2].contains("offline") && lines[2].contains("15s"));
        assert!(lines[3].contains("controller") && lines[3].contains("5m"));
        assert_eq!(DeviceKind::from_name("vehicle"), Some(DeviceKind::Vehicle));
        assert_eq!(DeviceKind::from_name("boat"), None);
    }

    /// The vehicle `rover-1` (100) in `state`: the header's words for the selected vehicle
    /// and its row's STANDING cell.
    fn header_and_row(state: &ConsoleState, now: MonoTime) -> (String, String, String) {
        let text = screen(state, now);
        let header = line_with(&text, "selected:").to_string();
        let row = row(&text, "rover-1").to_string();
        (text, header, row)
    }

    /// One consistent state everywhere: in each standing, the header and the row say the same
    /// words, and "you drive" lists the vehicle exactly when the row says YOU DRIVE.
    #[test]
    fn the_header_and_the_row_say_the_same_in_every_state() {
        use crate::model::Event::{Driving, VehicleStatus};
        let roles = |driving: Vec<DeviceId>, standby, paused| Driving {
            driving,
            holding: vec![],
            standby,
            paused,
        };
        let held = |mut health: VehicleHealth| {
            health.held = true;
            VehicleStatus {
                vehicle: 100,
                owner: 1,
                mode: Some(Mode::Auto),
                failsafe: true,
                link: "degraded: AUTO refused".into(),
                output: rove_core::msg::OutputState::Degraded,
                health,
            }
        };
        let cases: Vec<(&str, Vec<Event>, &str)> = vec![
            ("driving", vec![], "YOU DRIVE"),
            (
                "outranked",
                vec![seen(100, "rover-1", DeviceKind::Vehicle, 7)],
                "outranked by op-b (7)",
            ),
            (
                "yielded",
                vec![
                    roles(vec![], vec![100], vec![]),
                    seen(100, "rover-1", DeviceKind::Vehicle, 7),
                ],
                "yielded to op-b (7)",
            ),
            (
                "paused",
                vec![
                    roles(vec![], vec![], vec![100]),
                    seen(100, "rover-1", DeviceKind::Vehicle, 7),
                ],
                "paused · input not live · owner op-b (7)",
            ),
            (
                "standing by",
                vec![
                    roles(vec![], vec![], vec![]),
                    seen(100, "rover-1", DeviceKind::Vehicle, 7),
                ],
                "driven by op-b (7)",
            ),
            (
                "failsafe",
                vec![seen(100, "rover-1", DeviceKind::Vehicle, 100)],
                "failsafe: stopped, nobody drives",
            ),
            (
                "held",
                vec![held(VehicleHealth::UNKNOWN)],
                "held by autopilot · owner you (1)",
            ),
        ];
        for (name, events, words) in cases {
            let mut s = script();
            for e in events {
                s.apply(ms(800), e);
            }
            let (text, header, row) = header_and_row(&s, ms(1_000));
            // `--nocapture` shows each screen (docs/console.md has them).
            eprintln!(
                "== {name}\n{}",
                text.lines().take(10).collect::<Vec<_>>().join("\n")
            );
            assert!(
                header.contains(&format!("selected: rover-1 (100): {words}")),
                "{name}: header\n{text}"
            );
            assert!(row.contains(words), "{name}: row\n{text}");
            let drives = header.contains("you drive: rover-1 (100)");
            assert_eq!(drives, words == "YOU DRIVE", "{name}\n{text}");
            let text = s.standing_text(100).map(|(_, text)| text);
            assert_eq!(text.as_deref(), Some(words), "{name}");
        }
        // Offline, as time passes.
        let mut s = script();
        s.apply(ms(5_000), Event::Tick);
        let (text, header, row) = header_and_row(&s, ms(5_000));
        assert!(header.contains("rover-1 (100): offline"), "{text}");
        assert!(row.contains("offline"), "{text}");
        assert!(header.contains("you drive: nothing"), "{text}");
    }

    /// A low battery is a warning in the header, whichever vehicle is selected, and in the row.
    #[test]
    fn a_low_battery_is_a_warning_in_the_header_and_the_row() {
        let mut s = script();
        let health = VehicleHealth {
            battery_mv: 10_240,
            battery_pct: 8,
            battery_low: true,
            autopilot_mode: "HOLD".into(),
            armed: true,
            link_age_ms: 250,
            held: false,
        };
        s.apply(
            ms(800),
            Event::VehicleStatus {
                vehicle: 101,
                owner: 7,
                mode: Some(Mode::Manual),
                failsafe: false,
                link: "ok".into(),
                output: rove_core::msg::OutputState::Ok,
                health,
            },
        );
        let text = screen(&s, ms(1_000));
        eprintln!(
            "== low battery\n{}",
            text.lines().take(10).collect::<Vec<_>>().join("\n")
        );
        assert!(
            line_with(&text, "selected:").contains("LOW BATTERY rover-2 (101): 10.2V 8%"),
            "{text}"
        );
        let rover2 = row(&text, "rover-2");
        assert!(rover2.contains("LOW 10.2V 8%"), "{rover2}");
        assert!(rover2.contains("HOLD armed 0.2s"), "{rover2}");
        assert!(!row(&text, "rover-1").contains("LOW"), "{text}");
    }

    #[test]
    fn renders_on_tiny_terminals_without_panicking() {
        let mut s = script();
        s.apply(
            ms(1_000),
            Event::RequestIncoming(Prompt {
                vehicle: 100,
                requester: 7,
                src_priority: 340,
                deadline: ms(11_000),
            }),
        );
        for (w, h) in [(1, 1), (10, 5), (40, 12), (80, 24)] {
            let Ok(mut terminal) = Terminal::new(TestBackend::new(w, h)) else {
                panic!("backend");
            };
            assert!(terminal.draw(|f| render(f, &s, ms(2_000))).is_ok());
        }
    }
}
