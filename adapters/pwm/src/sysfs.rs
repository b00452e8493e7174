//! The Linux sysfs PWM backend: `/sys/class/pwm/pwmchipN/pwmM/…`, the kernel's generic PWM
//! interface (any board with a PWM driver, including the RaMstix and the Pi with the `pwm`
//! overlay).
//!
//! Per channel, at its first write (and again after any failed write):
//!
//! | step | file | value |
//! |---|---|---|
//! | 1 | `pwmchipN/export` | `M`, only if `pwmchipN/pwmM/` does not exist |
//! | 2 | `pwmchipN/pwmM/period` | period in ns (`20000000` for 20 ms) |
//! | 3 | `pwmchipN/pwmM/duty_cycle` | pulse in ns (`1500000` for 1500 µs) |
//! | 4 | `pwmchipN/pwmM/polarity` | `normal` / `inversed`, only if configured |
//! | 5 | `pwmchipN/pwmM/enable` | `1` |
//!
//! Afterwards only `duty_cycle` is written, and only when the pulse changes: the kernel holds
//! the value, so repeating it would only cost syscalls. Values are written as bare decimals
//! (the kernel accepts them with or without a newline). Nothing is unexported on drop, so the
//! last pulse (the safe state, written by the vehicle's `Drop`) stays on the pin after exit.

use crate::backend::PwmBackend;
use crate::config::{ChannelAddress, Polarity, PwmVehicleConfig};
use rove_core::MonoTime;
use rove_core::error::{Disposition, LinkError};
use std::fs::OpenOptions;
use std::io::{self, Write};
use std::path::{Path, PathBuf};

/// How a failed sysfs write is handled. Pure, so the policy is unit-tested.
///
/// - permission denied: fatal — a udev rule or group membership is missing; retrying cannot
///   help;
/// - invalid argument (`EINVAL`): fatal — the driver rejects the value (a period the hardware
///   cannot produce, a pulse longer than the period);
/// - anything else (missing file, `EBUSY`, I/O error): transient — the chip may be appearing
///   (the kernel creates `pwmM/` after `export`, udev fixes its permissions a moment later) or
///   a hot-plugged device may come back.
pub fn classify(kind: io::ErrorKind) -> Disposition {
    match kind {
        io::ErrorKind::PermissionDenied | io::ErrorKind::InvalidInput => Disposition::Fatal,
        _ => Disposition::Transient,
    }
}

/// Where one channel is in its setup.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum ChannelState {
    /// Never set up, or the last write failed: the next write runs the whole setup.
    Unprepared,
    /// Exported, period set, enabled; `duty_ns` is on the pin.
    Ready {
        /// The duty cycle last written, ns.
        duty_ns: u64,
    },
}

#[derive(Debug, Clone)]
struct SysfsChannel {
    address: ChannelAddress,
    polarity: Option<Polarity>,
    state: ChannelState,
}

/// One write made by the backend, as kept by [`SysfsBackend::with_journal`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SysfsWrite {
    /// The file.
    pub path: PathBuf,
    /// What was written.
    pub value: String,
}

/// PWM channels under a sysfs root (default `/sys/class/pwm`).
#[derive(Debug)]
pub struct SysfsBackend {
    root: PathBuf,
    period_ns: u64,
    channels: Vec<SysfsChannel>,
    /// Successful writes in order, kept only when asked for (tests, diagnosis): it grows with
    /// every write.
    journal: Option<Vec<SysfsWrite>>,
}

impl SysfsBackend {
    /// A backend for `config`'s channels and period under `root`. Touches nothing until the
    /// first write.
    pub fn new(root: PathBuf, config: &PwmVehicleConfig) -> Self {
        SysfsBackend {
            root,
            period_ns: u64::try_from(config.period.as_nanos()).unwrap_or(u64::MAX),
            channels: config
                .channels
                .iter()
                .map(|c| SysfsChannel {
                    address: c.address,
                    polarity: c.polarity,
                    state: ChannelState::Unprepared,
                })
                .collect(),
            journal: None,
        }
    }

    /// The same backend, also keeping every successful write in order (see
    /// [`SysfsBackend::journal`]).
    pub fn with_journal(mut self) -> Self {
        self.journal = Some(Vec::new());
        self
    }

    /// Successful writes so far, oldest first (empty unless built [`with_journal`]).
    ///
    /// [`with_journal`]: SysfsBackend::with_journal
    pub fn journal(&self) -> &[SysfsWrite] {
        self.journal.as_deref().unwrap_or(&[])
    }

    fn write_attr(&mut self, path: &Path, value: &str) -> Result<(), LinkError> {
        // No `create`: every file is the kernel's; a missing one is an error, not a new file.
        // `truncate` is ignored by sysfs and keeps a plain file (tests) exact.
        let result = OpenOptions::new()
            .write(true)
            .truncate(true)
            .open(path)
            .and_then(|mut f| f.write_all(value.as_bytes()));
        match result {
            Ok(()) => {
                if let Some(journal) = &mut self.journal {
                    journal.push(SysfsWrite {
                        path: path.to_path_buf(),
                        value: value.to_string(),
                    });
                }
                Ok(())
            }
            Err(e) => Err(LinkError {
                disposition: classify(e.kind()),
                detail: format!("sysfs PWM: writing {value:?} to {}: {e}", path.display()),
            }),
        }
    }

    fn setup(
        &mut self,
        chip: u32,
        channel: u32,
        duty_ns: u64,
        polarity: Option<Polarity>,
    ) -> Result<(), LinkError> {
        let chip_dir = self.root.join(format!("pwmchip{chip}"));
        let pwm_dir = chip_dir.join(format!("pwm{channel}"));
        if !pwm_dir.is_dir() {
            self.write_attr(&chip_dir.join("export"), &channel.to_string())?;
        }
        // Period before duty: the kernel rejects a duty cycle longer than the current period,
        // and a freshly exported channel has period 0.
        self.write_attr(&pwm_dir.join("period"), &self.period_ns.to_string())?;
        self.write_attr(&pwm_dir.join("duty_cycle"), &duty_ns.to_string())?;
        if let Some(p) = polarity {
            // Before enable: several drivers refuse a polarity change on a running channel.
            self.write_attr(&pwm_dir.join("polarity"), p.into())?;
        }
        self.write_attr(&pwm_dir.join("enable"), "1")
    }
}

impl PwmBackend for SysfsBackend {
    fn describe(&self) -> String {
        let names: Vec<String> = self
            .channels
            .iter()
            .map(|c| c.address.to_string())
            .collect();
        format!(
            "sysfs PWM under {} ({}; {} ns period)",
            self.root.display(),
            names.join(", "),
            self.period_ns
        )
    }

    fn channel_count(&self) -> usize {
        self.channels.len()
    }

    fn set_pulse_us(
        &mut self,
        _now: MonoTime,
        channel: usize,
        pulse_us: u16,
    ) -> Result<(), LinkError> {
        let Some(ch) = self.channels.get(channel).cloned() else {
            return Err(LinkError::fatal(format!(
                "sysfs PWM under {}: channel index {channel} out of range (have {})",
                self.root.display(),
                self.channels.len()
            )));
        };
        let ChannelAddress::Sysfs {
            chip,
            channel: number,
        } = ch.address
        else {
            return Err(LinkError::fatal(format!(
                "sysfs PWM under {}: channel {channel} is wired to {}, not a pwmchip channel",
                self.root.display(),
                ch.address
            )));
        };
        let duty_ns = u64::from(pulse_us) * 1_000;
        if duty_ns >= self.period_ns {
            return Err(LinkError::fatal(format!(
                "sysfs PWM pwmchip{chip}/pwm{number}: pulse {pulse_us} µs is not shorter than \
                 the period ({} ns)",
                self.period_ns
            )));
        }
        let result = match ch.state {
            ChannelState::Ready { duty_ns: current } if current == duty_ns => return Ok(()),
            ChannelState::Ready { .. } => {
                let path = self
                    .root
                    .join(format!("pwmchip{chip}/pwm{number}/duty_cycle"));
                self.write_attr(&path, &duty_ns.to_string())
            }
            ChannelState::Unprepared => self.setup(chip, number, duty_ns, ch.polarity),
        };
        if let Some(slot) = self.channels.get_mut(channel) {
            slot.state = match result {
                Ok(()) => ChannelState::Ready { duty_ns },
                // Whatever failed (the channel unexported, the chip gone), redo the whole setup
                // next time rather than assume which step still holds.
                Err(_) => ChannelState::Unprepared,
            };
        }
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::fs;

    /// Plays the kernel: a `pwmchipN` with `export`, and (if `exported`) `pwmM/` with its
    /// attribute files in their post-export state.
    fn fake_chip(root: &Path, chip: u32, exported: &[u32]) {
        let dir = root.join(format!("pwmchip{chip}"));
        fs::create_dir_all(&dir).expect("mkdir");
        fs::write(dir.join("export"), "").expect("export");
        for m in exported {
            fake_export(root, chip, *m);
        }
    }

    fn fake_export(root: &Path, chip: u32, channel: u32) {
        let dir = root.join(format!("pwmchip{chip}/pwm{channel}"));
        fs::create_dir_all(&dir).expect("mkdir");
        for (file, value) in [
            ("period", "0"),
            ("duty_cycle", "0"),
            ("enable", "0"),
            ("polarity", "normal"),
        ] {
            fs::write(dir.join(file), value).expect("attr");
        }
    }

    fn read(root: &Path, rel: &str) -> String {
        fs::read_to_string(root.join(rel)).expect("readable")
    }

    fn config(text: &str) -> PwmVehicleConfig {
        toml::from_str::<crate::PwmVehicleSettings>(text)
            .expect("parses")
            .validate()
            .expect("valid")
    }

    fn journal(backend: &SysfsBackend, root: &Path) -> Vec<(String, String)> {
        backend
            .journal()
            .iter()
            .map(|w| {
                (
                    w.path
                        .strip_prefix(root)
                        .expect("under root")
                        .display()
                        .to_string(),
                    w.value.clone(),
                )
            })
            .collect()
    }

    const TWO_CHANNELS: &str = "backend = \"sysfs\"\n\
        [[channels]]\nname = \"a\"\nsource = \"roll\"\nchannel = 0\n\
        [[channels]]\nname = \"b\"\nsource = \"throttle\"\nchip = 1\nchannel = 2\npolarity = \"inversed\"";

    #[test]
    fn sets_up_period_duty_polarity_enable_in_order_then_writes_only_changed_duty() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let root = tmp.path();
        fake_chip(root, 0, &[0]);
        fake_chip(root, 1, &[2]);
        let mut b = SysfsBackend::new(root.to_path_buf(), &config(TWO_CHANNELS)).with_journal();
        b.set_pulse_us(MonoTime::ZERO, 0, 1500).expect("ok");
        b.set_pulse_us(MonoTime::ZERO, 1, 1000).expect("ok");
        let s = |p: &str, v: &str| (p.to_string(), v.to_string());
        assert_eq!(
            journal(&b, root),
            [
                // Already exported: no write to `export`.
                s("pwmchip0/pwm0/period", "20000000"),
                s("pwmchip0/pwm0/duty_cycle", "1500000"),
                s("pwmchip0/pwm0/enable", "1"),
                s("pwmchip1/pwm2/period", "20000000"),
                s("pwmchip1/pwm2/duty_cycle", "1000000"),
                s("pwmchip1/pwm2/polarity", "inversed"),
                s("pwmchip1/pwm2/enable", "1"),
            ]
        );
        assert_eq!(read(root, "pwmchip0/export"), "");
        assert_eq!(
            read(root, "pwmchip0/pwm0/polarity"),
            "normal",
            "not configured"
        );
        assert_eq!(read(root, "pwmchip1/pwm2/polarity"), "inversed");
        b.set_pulse_us(MonoTime::ZERO, 0, 1500).expect("ok");
        assert_eq!(b.journal().len(), 7, "an unchanged pulse is not rewritten");
        b.set_pulse_us(MonoTime::ZERO, 0, 2000).expect("ok");
        assert_eq!(
            journal(&b, root)[7..],
            [s("pwmchip0/pwm0/duty_cycle", "2000000")]
        );
        assert_eq!(read(root, "pwmchip0/pwm0/duty_cycle"), "2000000");
        assert_eq!(read(root, "pwmchip0/pwm0/period"), "20000000");
        assert_eq!(read(root, "pwmchip0/pwm0/enable"), "1");
    }

    #[test]
    fn exports_a_missing_channel_and_retries_setup_once_the_kernel_created_it() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let root = tmp.path();
        fake_chip(root, 0, &[]);
        let cfg = config(
            "backend = \"sysfs\"\nperiod_us = 10000\n[[channels]]\nname = \"a\"\nsource = \"roll\"\nchannel = 3",
        );
        let mut b = SysfsBackend::new(root.to_path_buf(), &cfg).with_journal();
        let err = b
            .set_pulse_us(MonoTime::ZERO, 0, 1500)
            .expect_err("pwm3/ does not exist yet");
        assert_eq!(read(root, "pwmchip0/export"), "3");
        assert_eq!(err.disposition, Disposition::Transient);
        let period = root.join("pwmchip0/pwm3/period");
        assert!(
            err.detail.starts_with(&format!(
                "sysfs PWM: writing \"10000000\" to {}: ",
                period.display()
            )),
            "{err}"
        );
        // The kernel creates the channel directory.
        fake_export(root, 0, 3);
        b.set_pulse_us(MonoTime::ZERO, 0, 1200).expect("ok");
        let s = |p: &str, v: &str| (p.to_string(), v.to_string());
        assert_eq!(
            journal(&b, root),
            [
                s("pwmchip0/export", "3"),
                s("pwmchip0/pwm3/period", "10000000"),
                s("pwmchip0/pwm3/duty_cycle", "1200000"),
                s("pwmchip0/pwm3/enable", "1"),
            ],
            "exported once, then the full setup"
        );
    }

    #[test]
    fn a_failed_duty_write_leaves_the_channel_disabled_and_the_next_write_redoes_setup() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let root = tmp.path();
        fake_chip(root, 0, &[0]);
        let duty = root.join("pwmchip0/pwm0/duty_cycle");
        // A directory in place of the attribute: opening it for writing fails, even as root.
        fs::remove_file(&duty).expect("rm");
        fs::create_dir(&duty).expect("mkdir");
        let cfg = config(
            "backend = \"sysfs\"\n[[channels]]\nname = \"a\"\nsource = \"roll\"\nchannel = 0",
        );
        let mut b = SysfsBackend::new(root.to_path_buf(), &cfg);
        let err = b
            .set_pulse_us(MonoTime::ZERO, 0, 1500)
            .expect_err("duty fails");
        assert!(err.detail.contains(&duty.display().to_string()), "{err}");
        // Ordering seen on disk, without the journal: period written, enable not reached.
        assert_eq!(read(root, "pwmchip0/pwm0/period"), "20000000");
        assert_eq!(read(root, "pwmchip0/pwm0/enable"), "0");
        fs::remove_dir(&duty).expect("rmdir");
        fs::write(&duty, "0").expect("restore");
        fs::write(root.join("pwmchip0/pwm0/period"), "0").expect("reset period");
        b.set_pulse_us(MonoTime::ZERO, 0, 1600).expect("recovered");
        assert_eq!(
            read(root, "pwmchip0/pwm0/period"),
            "20000000",
            "setup redone"
        );
        assert_eq!(read(root, "pwmchip0/pwm0/duty_cycle"), "1600000");
        assert_eq!(read(root, "pwmchip0/pwm0/enable"), "1");
    }

    #[test]
    fn a_failed_write_on_a_ready_channel_redoes_setup_next_time() {
        let tmp = tempfile::tempdir().expect("tempdir");
        let root = tmp.path();
        fake_chip(root, 0, &[0]);
        let cfg = config(
            "backend = \"sysfs\"\n[[channels]]\nname = \"a\"\nsource = \"roll\"\nchannel = 0",
        );
        let mut b = SysfsBackend::new(root.to_path_buf(), &cfg).with_journal();
        b.set_pulse_us(MonoTime::ZERO, 0, 1500).expect("ok");
        // The channel disappears (unexported by someone else).
        fs::remove_dir_all(root.join("pwmchip0/pwm0")).expect("rm");
        assert!(b.set_pulse_us(MonoTime::ZERO, 0, 1700).is_err());
        fake_export(root, 0, 0);
        b.set_pulse_us(MonoTime::ZERO, 0, 1700).expect("ok");
        let tail: Vec<String> = b.journal()[3..]
            .iter()
            .map(|w| {
                w.path
                    .file_name()
                    .map(|f| f.to_string_lossy().into_owned())
                    .unwrap_or_default()
            })
            .collect();
        // The kernel re-created pwm0/ before the retry, so no export: the full setup again.
        assert_eq!(tail, ["period", "duty_cycle", "enable"]);
    }

    #[test]
    fn rejects_foreign_addresses_bad_indices_and_overlong_pulses() {
        let cfg =
            config("backend = \"sim\"\n[[channels]]\nname = \"a\"\nsource = \"roll\"\npin = 4");
        let mut b = SysfsBackend::new(PathBuf::from("/nonexistent"), &cfg);
        let err = b
            .set_pulse_us(MonoTime::ZERO, 0, 1500)
            .expect_err("GPIO address");
        assert_eq!(err.disposition, Disposition::Fatal);
        assert!(err.detail.contains("GPIO4"), "{err}");
        assert!(b.set_pulse_us(MonoTime::ZERO, 1, 1500).is_err());
        let cfg = config(
            "backend = \"sysfs\"\nperiod_us = 2500\n[[channels]]\nname = \"a\"\nsource = \"roll\"\nchannel = 0",
        );
        let mut b = SysfsBackend::new(PathBuf::from("/nonexistent"), &cfg);
        let err = b
            .set_pulse_us(MonoTime::ZERO, 0, 2500)
            .expect_err("too long");
        assert!(err.detail.contains("not shorter than the period"), "{err}");
    }

    #[test]
    fn classifies_io_errors() {
        use io::ErrorKind::*;
        let table = [
            (PermissionDenied, Disposition::Fatal),
            (InvalidInput, Disposition::Fatal),
            (NotFound, Disposition::Transient),
            (ResourceBusy, Disposition::Transient),
            (Other, Disposition::Transient),
        ];
        for (kind, want) in table {
            assert_eq!(classify(kind), want, "{kind:?}");
        }
    }
}
