//! `rove`: the gateway binary — vehicle and operator roles over DDS, `status`, `check-config` and
//! the demo (docs/design.md §8). `main` only parses and maps the result to an exit code.

use clap::{Parser, Subcommand};
use rove_gateway::{config, doctor, host, operator, output, runtime, status, vehicle};
use rove_tools::{self as tools, demo, harness};
use std::process::ExitCode;

/// rove — share control of robots between operators, safely.
#[derive(Debug, Parser)]
#[command(name = "rove", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run a simulated vehicle and three scripted operators and print every handover
    /// (join, preempt, quit, request/accept/finish, crash → failsafe).
    Demo {
        /// Play the story on the control core in this process (no DDS, no root needed).
        #[arg(long)]
        in_process: bool,
        /// With `--in-process`: do not pace the story in real time; print it at once.
        #[arg(long)]
        fast: bool,
        /// Every process joins with DDS Security, with certificates made for the story.
        #[arg(long, conflicts_with = "in_process")]
        secure: bool,
    },
    /// Run the vehicle role: take commands from the current owner only, drive the output.
    Vehicle {
        /// The vehicle's config file.
        #[arg(short, long, default_value = "/etc/rove/vehicle.toml")]
        config: std::path::PathBuf,
        /// Append every output (apply / safe, owner, values, times) as JSON lines to this file.
        #[arg(long)]
        record: Option<std::path::PathBuf>,
        /// Test hook, hidden from --help and only in debug builds (what `cargo test` runs; a
        /// release build such as the package has no such flag): SIGUSR1 blocks the control
        /// loop for MS milliseconds (as a hung device write would), so a test can see the
        /// watchdog keep-alives stop.
        #[cfg(debug_assertions)]
        #[arg(long, hide = true, value_name = "MS")]
        test_stall_on_sigusr1: Option<u64>,
    },
    /// Run a site's bridge: carry its devices to the other sites it is configured to meet,
    /// over Zenoh with mutual TLS, and theirs here (docs/remote.md).
    #[cfg(feature = "remote")]
    Bridge {
        /// The bridge's config file.
        #[arg(short, long, default_value = "/etc/rove/bridge.toml")]
        config: std::path::PathBuf,
    },
    /// Input devices for operators: list them, or show a device's mapped values live.
    Inputs {
        #[command(subcommand)]
        what: InputsCommand,
    },
    /// Drive the vehicle's configured outputs to their safe state and exit (systemd's
    /// ExecStopPost, or by hand after a crash).
    Failsafe {
        /// The vehicle's config file.
        #[arg(short, long, default_value = "/etc/rove/vehicle.toml")]
        config: std::path::PathBuf,
    },
    /// Run the operator role: stream commands to the vehicles this operator drives.
    Operator {
        /// The operator's config file.
        #[arg(short, long, default_value = "/etc/rove/operator.toml")]
        config: std::path::PathBuf,
        /// Ask this vehicle's owner for control (active handover) once the vehicle is seen.
        #[arg(long, value_name = "VEHICLE_ID")]
        request: Option<i64>,
        /// Append every RequestControl sent (with its send time) as JSON lines to this file.
        #[arg(long)]
        record: Option<std::path::PathBuf>,
        /// No console even on a terminal (services; the local API still runs if configured).
        #[arg(long)]
        headless: bool,
        /// Where the log goes while the console owns the terminal.
        #[arg(long, value_name = "FILE")]
        log_file: Option<std::path::PathBuf>,
        /// Test hook, hidden from --help and only in debug builds (what `cargo test` runs; a
        /// release build such as the package has no such flag): run with another device's
        /// certificate (`[security]`), so a test can see the others refuse it.
        #[cfg(debug_assertions)]
        #[arg(long, hide = true)]
        test_any_certificate: bool,
    },
    /// Show the devices on the network and who drives each vehicle.
    Status {
        /// DDS domain id.
        #[arg(long, default_value_t = 0)]
        domain: u16,
        /// Interface addresses DDS may use (repeatable; default loopback).
        #[arg(long = "interface", value_name = "IPV4")]
        interfaces: Vec<std::net::Ipv4Addr>,
        /// Print one JSON snapshot instead of a table.
        #[arg(long)]
        json: bool,
        /// Keep printing, once a second.
        #[arg(long)]
        watch: bool,
        /// How long to listen before the first snapshot, in ms.
        #[arg(long, default_value_t = 1500)]
        listen_ms: u64,
        /// Print every DeviceInfo and RequestControl sample as a JSON line, with its arrival
        /// time, until stopped.
        #[arg(long)]
        events: bool,
        /// Join a secured fleet with the DDS Security files in this directory (`rove keys add`).
        #[arg(long, value_name = "DIR")]
        security: Option<std::path::PathBuf>,
    },
    /// Who drove each vehicle, when and why: the vehicle's hash-chained audit log (oldest
    /// first); `--verify` checks the chain and fails on an edited, reordered or cut-short log.
    Audit {
        /// The vehicle (default: every vehicle with a log in the directory).
        #[arg(long)]
        vehicle: Option<i64>,
        /// The state directory (default: `$STATE_DIRECTORY`, else /var/lib/rove as root).
        #[arg(long, value_name = "DIR")]
        dir: Option<std::path::PathBuf>,
        /// Only check the chain (exit 1 on a break).
        #[arg(long)]
        verify: bool,
        /// The entries as JSON lines, as stored.
        #[arg(long)]
        json: bool,
    },
    /// Benchmarks.
    Bench {
        #[command(subcommand)]
        what: tools::Bench,
    },
    /// A fleet's DDS Security files: its CA and governance, each device's certificate, key and
    /// permissions (docs/security.md).
    #[cfg(feature = "security")]
    Keys {
        #[command(subcommand)]
        what: rove_gateway::certs::cli::KeysCommand,
    },
    /// What this computer offers (PWM chips, GPIO and the board, serial ports, CAN interfaces,
    /// input devices, the service user's groups) and, with `-c`, what a config needs from it
    /// (its channels, ports, interfaces and addresses): one line each, ok, missing or wrong
    /// with the fix. Exits 1 if anything is missing or wrong.
    Doctor {
        /// A vehicle or operator config whose needs to check.
        #[arg(short, long)]
        config: Option<std::path::PathBuf>,
        /// The service user.
        #[arg(long, default_value = "rove")]
        user: String,
        /// Test hook, hidden from --help: read /sys, /dev, /etc and /proc under DIR.
        #[arg(long, hide = true, value_name = "DIR", default_value = "/")]
        root: std::path::PathBuf,
    },
    /// Validate a vehicle or operator config; print the effective config with `--print`.
    CheckConfig {
        /// The TOML file.
        file: std::path::PathBuf,
        /// Print the effective configuration (defaults filled in).
        #[arg(long)]
        print: bool,
    },
}

#[derive(Debug, Subcommand)]
enum InputsCommand {
    /// Input devices (/dev/input/event*) with their axes, buttons and keys.
    List,
    /// Live mapped values of a device under an operator config's `[input]` mapping, so a
    /// mapping can be set up by looking (Ctrl-C ends).
    Show {
        /// Device path, by-id link, or name pattern (`*xbox*`).
        device: String,
        /// Operator config whose `[input]` mapping to use.
        #[arg(short, long)]
        config: std::path::PathBuf,
    },
}

/// Exit code for a configuration error, distinct from runtime failures so that systemd's
/// `RestartPreventExitStatus=` stops restart loops on a bad edit.
const EXIT_CONFIG: u8 = 78; // EX_CONFIG from sysexits.h

fn main() -> ExitCode {
    let cli = Cli::parse();
    let is_config = matches!(cli.command, Command::CheckConfig { .. });
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("rove: {err:#}");
            if is_config || err.is::<BadConfig>() {
                ExitCode::from(EXIT_CONFIG)
            } else {
                ExitCode::FAILURE
            }
        }
    }
}

/// A config file that cannot be used (unreadable, invalid): the role exits with [`EXIT_CONFIG`].
#[derive(Debug)]
struct BadConfig(String);

impl std::fmt::Display for BadConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for BadConfig {}

fn bad_config(err: anyhow::Error) -> anyhow::Error {
    BadConfig(format!("{err:#}")).into()
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Vehicle {
            config,
            record,
            #[cfg(debug_assertions)]
            test_stall_on_sigusr1,
        } => {
            #[cfg(not(debug_assertions))]
            let test_stall_on_sigusr1 = None;
            vehicle_cmd(config, record, test_stall_on_sigusr1)
        }
        Command::Failsafe { config } => failsafe_cmd(&config),
        Command::Audit {
            vehicle,
            dir,
            verify,
            json,
        } => rove_gateway::audit::cli(dir, vehicle, verify, json),
        #[cfg(feature = "remote")]
        Command::Bridge { config } => bridge_cmd(&config),
        Command::Operator {
            config,
            request,
            record,
            headless,
            log_file,
            #[cfg(debug_assertions)]
            test_any_certificate,
        } => {
            #[cfg(not(debug_assertions))]
            let test_any_certificate = false;
            operator_cmd(
                config,
                request,
                record,
                headless,
                log_file,
                test_any_certificate,
            )
        }
        Command::Status {
            domain,
            interfaces,
            json,
            watch,
            listen_ms,
            events,
            security,
        } => status_cmd(status::Options {
            domain_id: domain,
            interfaces,
            listen: std::time::Duration::from_millis(listen_ms),
            json,
            watch,
            events,
            security,
        }),
        Command::Demo {
            in_process,
            fast,
            secure,
        } => demo_cmd(in_process, fast, secure),
        Command::Inputs {
            what: InputsCommand::List,
        } => inputs_list(),
        Command::Inputs {
            what: InputsCommand::Show { device, config },
        } => show_input(&device, &config),
        Command::Bench { what } => tools::run(what, &std::env::current_exe()?),
        #[cfg(feature = "security")]
        Command::Keys { what } => rove_gateway::certs::cli::run(what),
        Command::Doctor { config, user, root } => {
            let loaded = match &config {
                Some(path) => Some(config::load_any(path).map_err(bad_config)?.0),
                None => None,
            };
            let found = doctor::check(&doctor::Roots(root), &user, loaded.as_ref());
            for finding in &found {
                println!("{finding}");
            }
            let bad = found
                .iter()
                .filter(|f| matches!(f.status, doctor::Status::Missing | doctor::Status::Wrong))
                .count();
            match bad {
                0 => Ok(()),
                n => Err(anyhow::anyhow!("{n} missing or wrong")),
            }
        }
        Command::CheckConfig { file, print } => {
            let (loaded, effective) = config::load_any(&file)?;
            let role = match &loaded {
                config::AnyConfig::Vehicle(_) => "vehicle",
                config::AnyConfig::Operator(_) => "operator",
                config::AnyConfig::Bridge(_) => "bridge",
            };
            // With --print, stdout is the effective TOML alone (`> file` loads again); the
            // verdict goes to stderr.
            if print {
                println!("{effective}");
                eprintln!("{}: valid {role} config", file.display());
            } else {
                println!("{}: valid {role} config", file.display());
            }
            Ok(())
        }
    }
}

/// `rove vehicle`.
fn vehicle_cmd(
    path: std::path::PathBuf,
    record: Option<std::path::PathBuf>,
    stall_ms: Option<u64>,
) -> anyhow::Result<()> {
    let config = load_vehicle(&path)?;
    let options = vehicle::Options {
        config_path: path,
        record,
        stall_on_sigusr1: stall_ms.map(std::time::Duration::from_millis),
    };
    tokio_runtime()?.block_on(host::vehicle(config, options))
}

/// A vehicle config for `rove vehicle` and `rove failsafe`: loaded, logging started, and the
/// MAVLink output told where the running vehicle keeps what it learns (which the failsafe
/// reads).
fn load_vehicle(path: &std::path::Path) -> anyhow::Result<config::VehicleConfig> {
    let mut config = config::load_vehicle(path).map_err(bad_config)?;
    runtime::init_logging(config.common.log_filter.as_deref());
    output::keep_learned(&mut config.output, config.common.id);
    Ok(config)
}

/// `rove bridge`: on a multi-thread runtime of one worker (Zenoh refuses a current-thread
/// runtime; it runs its own threads besides).
#[cfg(feature = "remote")]
fn bridge_cmd(path: &std::path::Path) -> anyhow::Result<()> {
    let config = config::load_bridge(path).map_err(bad_config)?;
    // Missing or unreadable keys are a config error (exit 78): restarting cannot help.
    config.link.check_files().map_err(bad_config)?;
    // So are a revoked site and a secured site's missing proxy certificates.
    rove_gateway::bridge::check(&config).map_err(bad_config)?;
    let filter = match config.common.log_filter.as_deref() {
        Some(f) if f.contains("zenoh") => f.to_string(),
        Some(f) => format!("{f},zenoh=warn"),
        None => format!("{},zenoh=warn", runtime::DEFAULT_LOG_FILTER),
    };
    runtime::init_logging_with(
        Some(&filter),
        Some(rove_gateway::bridge::tls_watch(&config)),
    );
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let shutdown = runtime::shutdown_signal()?;
        rove_gateway::bridge::run(
            config,
            rove_gateway::sdnotify::Notifier::from_env(),
            shutdown,
        )
        .await
    })
}

/// `rove failsafe`: for systemd's `ExecStopPost`.
fn failsafe_cmd(config: &std::path::Path) -> anyhow::Result<()> {
    let config = load_vehicle(config)?;
    let what =
        output::failsafe(&config.output).map_err(|e| anyhow::anyhow!("failsafe: {}", e.detail))?;
    println!("rove failsafe: {what}: safe state written");
    Ok(())
}

/// `rove operator`: the console on a terminal (the log to a file then), headless otherwise.
fn operator_cmd(
    path: std::path::PathBuf,
    request: Option<i64>,
    record: Option<std::path::PathBuf>,
    headless: bool,
    log_file: Option<std::path::PathBuf>,
    test_any_certificate: bool,
) -> anyhow::Result<()> {
    // The test hook exists only in debug builds.
    #[cfg(not(debug_assertions))]
    let test_any_certificate = {
        let _ = test_any_certificate;
        false
    };
    use std::io::IsTerminal;
    let config = config::load_operator(&path).map_err(bad_config)?;
    let console = !headless && std::io::stdin().is_terminal() && std::io::stdout().is_terminal();
    if console {
        // The console owns the screen: the log goes to a file.
        let log = log_file.unwrap_or_else(|| {
            std::env::temp_dir().join(format!("rove-operator-{}.log", config.common.id))
        });
        eprintln!(
            "rove operator: console on this terminal; log in {}",
            log.display()
        );
        runtime::init_logging_to_file(config.common.log_filter.as_deref(), &log)?;
    } else {
        runtime::init_logging(config.common.log_filter.as_deref());
    }
    let options = operator::Options {
        config_path: path,
        request,
        record,
        console,
        any_certificate: test_any_certificate,
    };
    tokio_runtime()?
        .block_on(async { host::operator(config, options, runtime::shutdown_signal()?).await })
}

/// `rove demo`: as processes in a namespace, else (not root) in this process.
fn demo_cmd(in_process: bool, fast: bool, secure: bool) -> anyhow::Result<()> {
    if !in_process {
        let rove = std::env::current_exe()?;
        tools::cleanup::stop_on_signals()?;
        match demo::run_processes(&rove, secure, &mut |line| println!("{line}")) {
            Ok(()) => return Ok(()),
            // Without namespaces (not root), fall back to the in-process story.
            Err(e) if e.is::<harness::NoNamespace>() && !secure => {
                eprintln!("rove demo: {e:#}; playing the story in-process instead");
            }
            Err(e) => return Err(e),
        }
    }
    demo::run(!fast, |line| println!("{line}"))?;
    Ok(())
}

/// `rove inputs list`.
fn inputs_list() -> anyhow::Result<()> {
    let devices = rove_inputs::device::list_devices();
    if devices.is_empty() {
        println!("no input devices in /dev/input (none plugged in, or no evdev here)");
    }
    for d in devices {
        match d.summary {
            Ok(summary) => println!("{}\n{summary}\n", d.path.display()),
            Err(e) => println!("{}: cannot open: {e}\n", d.path.display()),
        }
    }
    Ok(())
}

/// `rove status`: on loopback unless interfaces are given.
fn status_cmd(mut options: status::Options) -> anyhow::Result<()> {
    if options.interfaces.is_empty() {
        options.interfaces = vec![std::net::Ipv4Addr::LOCALHOST];
    }
    tokio_runtime()?.block_on(status::run(options))
}

/// One single-threaded runtime per process: each role is one event loop, and rustdds runs its
/// own network threads, so more worker threads would only add hand-offs.
fn tokio_runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?)
}

/// `rove inputs show`: the device under the config's mapping, one status line per change.
fn show_input(device: &str, config: &std::path::Path) -> anyhow::Result<()> {
    use rove_core::adapter::InputSource;
    let operator = config::load_operator(config)?;
    let config::InputChoice::Device(input) = operator.input else {
        anyhow::bail!(
            "{}: [input] has no device mapping (source = \"joystick\" or \"keyboard\")",
            config.display()
        );
    };
    let selector = if device.starts_with('/') {
        rove_inputs::config::DeviceSelector::Path(device.into())
    } else {
        rove_inputs::config::DeviceSelector::Name(device.to_string())
    };
    let mut source = rove_inputs::open_mapped(&input.with_device(selector))
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    eprintln!("{} (Ctrl-C ends)", source.describe());
    let start = std::time::Instant::now();
    let mut shown = String::new();
    loop {
        let now = rove_core::MonoTime::ZERO + start.elapsed();
        while let Ok(Some(_)) = source.poll(now) {}
        let line = source.status().to_string();
        if line != shown {
            println!("{line}");
            shown = line;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}
