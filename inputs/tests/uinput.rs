//! End-to-end through the kernel: a uinput virtual gamepad read by [`EvdevSource`], including
//! unplugging it. Needs `/dev/uinput` and permission to use it (root or the `uinput` group), so
//! it is ignored by default and fails, saying why, when run without them. `scripts/test` runs it
//! with `--ignored` where `/dev/uinput` exists; where it does not (these VMs' kernels have no
//! uinput), its final line counts it as skipped.

use evdev::uinput::VirtualDevice;
use evdev::{AbsInfo, AbsoluteAxisCode, AttributeSet, KeyCode, UinputAbsSetup};
use rove_core::adapter::{InputEvent, InputSource};
use rove_core::time::MonoTime;
use rove_inputs::config::DeviceSelector;
use rove_inputs::{EvdevSource, InputSettings};
use std::path::Path;
use std::time::{Duration, Instant};

fn missing(why: &str) -> ! {
    panic!("the uinput end-to-end test cannot run here: {why}");
}

/// Polls until an event arrives or `within` passes.
fn next_event(source: &mut EvdevSource, start: Instant, within: Duration) -> Option<InputEvent> {
    let deadline = Instant::now() + within;
    loop {
        let now =
            MonoTime::from_nanos(u64::try_from(start.elapsed().as_nanos()).unwrap_or(u64::MAX));
        match source.poll(now) {
            Ok(Some(e)) => return Some(e),
            Ok(None) => {}
            Err(e) => panic!("source failed: {e}"),
        }
        if Instant::now() > deadline {
            return None;
        }
        std::thread::sleep(Duration::from_millis(2));
    }
}

#[test]
#[ignore = "needs /dev/uinput (a kernel with CONFIG_INPUT_UINPUT); scripts/test runs it where it exists"]
fn virtual_gamepad_drives_and_unplug_is_lost() {
    if !Path::new("/dev/uinput").exists() {
        missing("/dev/uinput does not exist (kernel without CONFIG_INPUT_UINPUT)");
    }
    let mut keys = AttributeSet::<KeyCode>::new();
    keys.insert(KeyCode::BTN_SOUTH);
    keys.insert(KeyCode::BTN_TL);
    let info = AbsInfo::new(0, -32768, 32767, 16, 128, 0);
    let built = VirtualDevice::builder().and_then(|b| {
        b.name("rove-inputs test pad")
            .with_keys(&keys)?
            .with_absolute_axis(&UinputAbsSetup::new(AbsoluteAxisCode::ABS_X, info))?
            .with_absolute_axis(&UinputAbsSetup::new(AbsoluteAxisCode::ABS_Y, info))?
            .build()
    });
    let mut pad = match built {
        Ok(pad) => pad,
        Err(e) => missing(&format!("cannot create a uinput device: {e}")),
    };
    let node = pad
        .enumerate_dev_nodes_blocking()
        .ok()
        .and_then(|mut nodes| nodes.next())
        .and_then(Result::ok);
    let Some(node) = node else {
        missing("the virtual device got no /dev/input node");
    };
    let config = toml::from_str::<InputSettings>(
        "source = \"joystick\"\n[axes.roll]\nabs = \"ABS_X\"\ndeadzone_pct = 2.0\n[buttons]\ndeadman = \"BTN_TL\"\n",
    )
    .expect("parses")
    .validate()
    .expect("valid");
    let mut source = EvdevSource::spawn(
        DeviceSelector::Path(node),
        false,
        Duration::from_millis(50),
        config.mapping.clone(),
    )
    .expect("reader starts");
    let start = Instant::now();
    // Let the reader open the device before events are emitted.
    std::thread::sleep(Duration::from_millis(200));
    let emit = |pad: &mut VirtualDevice, events: &[(u16, u16, i32)]| {
        let events: Vec<_> = events
            .iter()
            .map(|(t, c, v)| evdev::InputEvent::new(*t, *c, *v))
            .collect();
        pad.emit(&events).expect("emit");
    };
    emit(&mut pad, &[(1, KeyCode::BTN_TL.0, 1)]);
    assert_eq!(
        next_event(&mut source, start, Duration::from_secs(2)),
        Some(InputEvent::Deadman(true))
    );
    assert!(matches!(
        next_event(&mut source, start, Duration::from_secs(2)),
        Some(InputEvent::Axes(_))
    ));
    emit(&mut pad, &[(3, AbsoluteAxisCode::ABS_X.0, 32767)]);
    match next_event(&mut source, start, Duration::from_secs(2)) {
        Some(InputEvent::Axes(m)) => assert_eq!(m.roll, 32767),
        other => panic!("expected full right roll, got {other:?}"),
    }
    drop(pad);
    match next_event(&mut source, start, Duration::from_secs(2)) {
        Some(InputEvent::Lost { reason }) => eprintln!("unplug reported: {reason}"),
        other => panic!("expected Lost after destroying the device, got {other:?}"),
    }
}
