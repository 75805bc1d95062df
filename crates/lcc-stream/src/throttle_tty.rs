//! `lcc-stream throttle` at a terminal: keys drive the train, and a status line shows what the
//! train answered (each command is read back with Query Speeds or Query Function).
//!
//! Keys: Up/Down (or + and -) change the speed by [`SPEED_STEP`] km/h; Right/Left (or f and r)
//! the direction; 0-9 toggle F0-F9; Space is an emergency stop (the next speed key starts the
//! train again from 0); q, Esc or Ctrl-C release the train and end the run. The terminal is in
//! raw mode while it runs and is restored on every way out ([`RawMode`] restores it on drop,
//! unwinding included).

use std::io::Write as _;

use crossterm::event::{Event, KeyCode, KeyEvent, KeyEventKind, KeyModifiers};
use openlcb_tokio::openlcb_node::traction::{Speed, ThrottleEvent, TractionCommand};
use openlcb_tokio::{Node, NodeId, ThrottleEvents};
use tokio::sync::mpsc;

use crate::net;
use crate::outcome::{Failure, Outcome};
use crate::peer::Peer;
use crate::throttle::send;

/// Km/h a speed key adds or takes away.
pub(crate) const SPEED_STEP: f32 = 5.0;
/// The highest speed the keys set, in km/h.
pub(crate) const MAX_KMH: f32 = 300.0;
/// Functions the digit keys switch (F0-F9).
const DIGIT_FUNCTIONS: usize = 10;

/// What a key asks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum Action {
    /// One speed step up.
    Faster,
    /// One speed step down (not below 0).
    Slower,
    /// Run forwards.
    Forward,
    /// Run in reverse.
    Reverse,
    /// Toggle a function.
    Toggle(u32),
    /// Emergency stop.
    Estop,
    /// Release the train and end.
    Release,
}

/// The action of `key`, if it is one of the throttle's.
pub(crate) fn action_of(key: &KeyEvent) -> Option<Action> {
    if key.kind == KeyEventKind::Release {
        return None;
    }
    Some(match key.code {
        KeyCode::Char('c') if key.modifiers.contains(KeyModifiers::CONTROL) => Action::Release,
        KeyCode::Up | KeyCode::Char('+') => Action::Faster,
        KeyCode::Down | KeyCode::Char('-') => Action::Slower,
        KeyCode::Right | KeyCode::Char('f') => Action::Forward,
        KeyCode::Left | KeyCode::Char('r') => Action::Reverse,
        KeyCode::Char(digit @ '0'..='9') => Action::Toggle(u32::from(digit) - u32::from('0')),
        KeyCode::Char(' ') => Action::Estop,
        KeyCode::Char('q') | KeyCode::Esc => Action::Release,
        _ => return None,
    })
}

/// What the throttle asks of the train, and what the train last said.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Drive {
    /// The speed asked for, in km/h (0 or more).
    pub(crate) kmh: f32,
    /// The direction asked for.
    pub(crate) forward: bool,
    /// F0-F9 as the train last answered.
    pub(crate) functions: [bool; DIGIT_FUNCTIONS],
    /// The train's answer: its Set Speed and emergency stop.
    pub(crate) answered: Option<(Speed, bool)>,
}

impl Drive {
    /// Standing, forwards, every function off.
    pub(crate) fn new() -> Self {
        Drive { kmh: 0.0, forward: true, functions: [false; DIGIT_FUNCTIONS], answered: None }
    }

    fn speed(&self) -> Speed {
        let magnitude = Speed::from_f32(self.kmh / 3.6);
        if self.forward { magnitude } else { magnitude.reversed() }
    }

    /// The command for `action` and the query that reads its effect back; `None` for
    /// [`Action::Release`] (the caller releases) or a step that changes nothing.
    pub(crate) fn command(&mut self, action: Action) -> Option<(TractionCommand, TractionCommand)> {
        let set_speed = |drive: &Self| TractionCommand::SetSpeed { speed: drive.speed(), forwarded: false };
        let speeds = TractionCommand::QuerySpeeds;
        match action {
            Action::Faster => self.kmh = (self.kmh + SPEED_STEP).min(MAX_KMH),
            Action::Slower => self.kmh = (self.kmh - SPEED_STEP).max(0.0),
            Action::Forward => self.forward = true,
            Action::Reverse => self.forward = false,
            Action::Toggle(address) => {
                let on = !self.functions.get(address as usize).copied().unwrap_or(false);
                let value = u16::from(on);
                let set = TractionCommand::SetFunction { address, value, forwarded: false };
                return Some((set, TractionCommand::QueryFunction { address }));
            }
            Action::Estop => {
                self.kmh = 0.0;
                return Some((TractionCommand::EmergencyStop { forwarded: false }, speeds));
            }
            Action::Release => return None,
        }
        Some((set_speed(self), speeds))
    }

    /// Takes in what the train answered about `train`.
    pub(crate) fn answer(&mut self, train: NodeId, event: &ThrottleEvent) {
        match *event {
            ThrottleEvent::Speeds { train: t, set, emergency_stop, .. } if t == train => {
                self.answered = Some((set, emergency_stop));
            }
            ThrottleEvent::Function { train: t, address, value } if t == train => {
                if let Some(slot) = self.functions.get_mut(address as usize) {
                    *slot = value != 0;
                }
            }
            _ => {}
        }
    }

    /// The status line.
    pub(crate) fn status(&self, train: &str) -> String {
        let speed = match self.answered {
            None => "speed not read yet".to_string(),
            Some((set, true)) => format!("EMERGENCY STOP ({})", direction(set)),
            Some((set, false)) => format!("{:.0} km/h {}", set.to_f32().abs() * 3.6, direction(set)),
        };
        let on: Vec<String> =
            self.functions.iter().enumerate().filter(|(_, on)| **on).map(|(i, _)| format!("F{i}")).collect();
        let functions = if on.is_empty() { "no function on".to_string() } else { on.join(" ") };
        format!("{train}: {speed}; {functions}  [Up/Down speed, Left/Right direction, 0-9, Space stop, q]")
    }
}

fn direction(speed: Speed) -> &'static str {
    if speed.is_reverse() { "reverse" } else { "forward" }
}

/// The terminal in raw mode; restored when dropped.
pub(crate) struct RawMode(());

impl RawMode {
    pub(crate) fn enter() -> Result<Self, String> {
        crossterm::terminal::enable_raw_mode().map_err(|e| format!("cannot put the terminal in raw mode: {e}"))?;
        Ok(RawMode(()))
    }
}

impl Drop for RawMode {
    fn drop(&mut self) {
        let _ = crossterm::terminal::disable_raw_mode();
        eprintln!();
    }
}

/// The terminal's keys, read on a thread of their own (reading blocks).
fn keys() -> mpsc::Receiver<KeyEvent> {
    let (sender, keys) = mpsc::channel(16);
    std::thread::spawn(move || {
        while let Ok(event) = crossterm::event::read() {
            if let Event::Key(key) = event
                && sender.blocking_send(key).is_err()
            {
                break;
            }
        }
    });
    keys
}

fn redraw(line: &str) {
    let mut err = std::io::stderr();
    let _ = write!(err, "\r\x1b[2K{line}");
    let _ = err.flush();
}

/// Drives `train` from the keys until a release key, Ctrl-C, a takeover or the train's loss.
pub(crate) async fn drive(
    node: &Node,
    events: &mut ThrottleEvents,
    train: NodeId,
    interrupt: &mut net::Interrupt,
) -> Result<Outcome, Failure> {
    let _raw = match RawMode::enter() {
        Ok(raw) => raw,
        Err(why) => {
            eprintln!("lcc-stream throttle: {why}");
            return Ok(Outcome::Error);
        }
    };
    let name = Peer::of(train).to_string();
    let mut keys = keys();
    let mut state = Drive::new();
    send(node, train, TractionCommand::QuerySpeeds).await?;
    redraw(&state.status(&name));
    loop {
        tokio::select! {
            key = keys.recv() => {
                let Some(key) = key else { return Ok(Outcome::Ok) };
                match action_of(&key) {
                    Some(Action::Release) => return Ok(Outcome::Ok),
                    Some(action) => {
                        if let Some((command, query)) = state.command(action) {
                            send(node, train, command).await?;
                            send(node, train, query).await?;
                        }
                    }
                    None => {}
                }
            }
            event = events.next() => {
                let Some(event) = event else { return Ok(Outcome::ConnectionLost) };
                match event {
                    ThrottleEvent::ControllerLost { train: t, to } if t == train => {
                        redraw(&format!("{name}: taken over by {to}"));
                        return Ok(Outcome::Ok);
                    }
                    ThrottleEvent::TrainLost { train: t } if t == train => {
                        redraw(&format!("{name}: left the network"));
                        return Ok(Outcome::NotFound);
                    }
                    ThrottleEvent::Rejected { train: t, code } if t == train => {
                        redraw(&format!("{name}: refused a command (0x{:04X})", code.0));
                        continue;
                    }
                    event => state.answer(train, &event),
                }
                redraw(&state.status(&name));
            }
            () = interrupt.wait() => return Ok(Outcome::Ok),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn key(code: KeyCode) -> KeyEvent {
        KeyEvent::new(code, KeyModifiers::NONE)
    }

    #[test]
    fn keys_map_to_the_throttles_actions() {
        assert_eq!(action_of(&key(KeyCode::Up)), Some(Action::Faster));
        assert_eq!(action_of(&key(KeyCode::Char('-'))), Some(Action::Slower));
        assert_eq!(action_of(&key(KeyCode::Left)), Some(Action::Reverse));
        assert_eq!(action_of(&key(KeyCode::Char('f'))), Some(Action::Forward));
        assert_eq!(action_of(&key(KeyCode::Char('7'))), Some(Action::Toggle(7)));
        assert_eq!(action_of(&key(KeyCode::Char(' '))), Some(Action::Estop));
        assert_eq!(action_of(&key(KeyCode::Char('q'))), Some(Action::Release));
        assert_eq!(action_of(&KeyEvent::new(KeyCode::Char('c'), KeyModifiers::CONTROL)), Some(Action::Release));
        assert_eq!(action_of(&key(KeyCode::Char('x'))), None);
        let mut released = key(KeyCode::Up);
        released.kind = KeyEventKind::Release;
        assert_eq!(action_of(&released), None, "a key's release is no second press");
    }

    #[test]
    fn speed_steps_stay_between_zero_and_the_top_and_keep_the_direction() {
        let mut drive = Drive::new();
        assert_eq!(
            drive.command(Action::Slower),
            Some((
                TractionCommand::SetSpeed { speed: Speed::ZERO_FORWARD, forwarded: false },
                TractionCommand::QuerySpeeds
            ))
        );
        drive.command(Action::Faster);
        drive.command(Action::Faster);
        assert_eq!(drive.kmh, 2.0 * SPEED_STEP);
        let Some((TractionCommand::SetSpeed { speed, .. }, _)) = drive.command(Action::Reverse) else { panic!() };
        assert!(speed.is_reverse() && (speed.to_f32() * 3.6 + 10.0).abs() < 0.1, "{speed}");
        for _ in 0..100 {
            drive.command(Action::Faster);
        }
        assert_eq!(drive.kmh, MAX_KMH);
        assert!(matches!(drive.command(Action::Estop), Some((TractionCommand::EmergencyStop { .. }, _))));
        assert_eq!(drive.kmh, 0.0, "after an emergency stop the speed keys start from 0");
        assert_eq!(drive.command(Action::Release), None);
    }

    #[test]
    fn a_function_key_toggles_what_the_train_last_answered() {
        let train = NodeId::new(0x0501_0101_2201).unwrap();
        let mut drive = Drive::new();
        let toggle = |drive: &mut Drive| match drive.command(Action::Toggle(2)) {
            Some((
                TractionCommand::SetFunction { address: 2, value, .. },
                TractionCommand::QueryFunction { address: 2 },
            )) => value,
            other => panic!("{other:?}"),
        };
        assert_eq!(toggle(&mut drive), 1);
        // Not answered yet: still off here, so the same key asks for on again.
        assert_eq!(toggle(&mut drive), 1);
        drive.answer(train, &ThrottleEvent::Function { train, address: 2, value: 1 });
        assert_eq!(toggle(&mut drive), 0);
        let other = NodeId::new(0x0501_0101_2202).unwrap();
        drive.answer(other, &ThrottleEvent::Function { train: other, address: 3, value: 1 });
        drive.answer(
            train,
            &ThrottleEvent::Speeds {
                train,
                set: Speed::from_f32(-10.0 / 3.6),
                emergency_stop: false,
                commanded: Speed::NAN,
                actual: Speed::NAN,
            },
        );
        let status = drive.status("DCC 3");
        assert!(status.starts_with("DCC 3: 10 km/h reverse; F2"), "{status}");
    }
}
