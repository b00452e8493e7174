//! The browser operator console (`[web]`, docs/web.md) in a real browser: Debian's chromium,
//! driven through chromedriver (WebDriver, the `fantoccini` client) with touch emulation, both
//! inside the test's network namespace. The test reaches chromedriver through a Unix socket
//! (socat in the namespace), so nothing of the browser ever runs outside it.
//!
//! `ROVE_WEB_SHOTS=DIR` saves the phone and tablet screenshots there (docs/web.md's come from
//! this).

use crate::util::{Rig, eventually, records, wait_for_output, wall_us};
use fantoccini::{Client, ClientBuilder, Locator};
use rove_testkit::require_tool;
use serde_json::{Value, json};
use std::future::Future;
use std::path::{Path, PathBuf};
use std::pin::Pin;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

const PHONE: i64 = 40;
const LAPTOP: i64 = 11;
const VEHICLE: i64 = 100;
const PORT: u16 = 8443;

/// Connects hyper (under fantoccini) to a Unix socket, whatever the URL says.
#[derive(Clone, Debug)]
struct UnixConnector(Arc<PathBuf>);

type Connecting = Pin<
    Box<
        dyn Future<Output = std::io::Result<hyper_util::rt::TokioIo<tokio::net::UnixStream>>>
            + Send,
    >,
>;

impl tower_service::Service<hyper::Uri> for UnixConnector {
    type Response = hyper_util::rt::TokioIo<tokio::net::UnixStream>;
    type Error = std::io::Error;
    type Future = Connecting;

    fn poll_ready(&mut self, _: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, _: hyper::Uri) -> Self::Future {
        let path = Arc::clone(&self.0);
        Box::pin(async move {
            let stream = tokio::net::UnixStream::connect(&*path).await?;
            Ok(hyper_util::rt::TokioIo::new(stream))
        })
    }
}

/// chromedriver's DevTools passthrough (`goog/cdp/execute`) with a command and its parameters.
#[derive(Debug)]
struct Cdp(Value);

impl fantoccini::wd::WebDriverCompatibleCommand for Cdp {
    fn endpoint(
        &self,
        base: &url::Url,
        session: Option<&str>,
    ) -> Result<url::Url, url::ParseError> {
        base.join(&format!(
            "session/{}/goog/cdp/execute",
            session.unwrap_or_default()
        ))
    }

    fn method_and_body(&self, _: &url::Url) -> (hyper::Method, Option<String>) {
        (hyper::Method::POST, Some(self.0.to_string()))
    }
}

/// A viewport: CSS pixels and touch.
#[derive(Clone, Copy, Debug)]
struct Viewport {
    width: u32,
    height: u32,
}

const PHONE_VIEW: Viewport = Viewport {
    width: 360,
    height: 740,
};
const TABLET_VIEW: Viewport = Viewport {
    width: 1024,
    height: 768,
};

/// chromedriver and chromium in the rig's namespace, and a WebDriver session.
struct Browser {
    /// Where the first finger is down, if it is.
    finger: std::cell::Cell<Option<(i64, i64)>>,
    rt: tokio::runtime::Runtime,
    client: Client,
    driver: Child,
    bridge: Child,
}

impl Browser {
    fn start(rig: &Rig, view: Viewport, port: u16) -> Browser {
        require_tool("chromium", "chromium");
        require_tool("chromedriver", "chromium-driver");
        require_tool("socat", "socat");
        let log =
            std::fs::File::create(rig.dir.join(format!("chromedriver-{port}.log"))).expect("log");
        let in_ns = |program: &str| {
            let mut c = Command::new("ip");
            c.args(["netns", "exec", &rig.ns, program]);
            c
        };
        let driver = in_ns("chromedriver")
            .arg(format!("--port={port}"))
            .stdout(log.try_clone().expect("log"))
            .stderr(log)
            .spawn()
            .expect("chromedriver");
        let socket = rig.dir.join(format!("webdriver-{port}.sock"));
        let bridge = in_ns("socat")
            .arg(format!("UNIX-LISTEN:{},fork", socket.display()))
            .arg(format!("TCP:127.0.0.1:{port}"))
            .stderr(Stdio::null())
            .spawn()
            .expect("socat");
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("runtime");
        let caps = json!({
            "browserName": "chrome",
            // The console's certificate is self-signed (made at start).
            "acceptInsecureCerts": true,
            "goog:chromeOptions": {
                "binary": "/usr/bin/chromium",
                "args": ["--headless=new", "--no-sandbox", "--disable-gpu",
                         "--disable-dev-shm-usage", "--no-first-run"],
                "mobileEmulation": {
                    "deviceMetrics": {
                        "width": view.width, "height": view.height,
                        "pixelRatio": 2, "touch": true,
                    },
                },
            },
        });
        let Value::Object(caps) = caps else {
            unreachable!("a JSON object")
        };
        let connector = UnixConnector(Arc::new(socket));
        let client = eventually("chromedriver takes a session", || {
            rt.block_on(
                ClientBuilder::new(connector.clone())
                    .capabilities(caps.clone())
                    .connect("http://localhost"),
            )
        });
        Browser {
            finger: std::cell::Cell::new(None),
            rt,
            client,
            driver,
            bridge,
        }
    }

    fn run<T>(&self, f: impl Future<Output = T>) -> T {
        self.rt.block_on(f)
    }

    fn js(&self, script: &str) -> Value {
        self.run(self.client.execute(script, vec![]))
            .unwrap_or_else(|e| panic!("{script}: {e}"))
    }

    fn text(&self, css: &str) -> String {
        let script = format!("return document.querySelector({css:?}).textContent");
        self.js(&script).as_str().unwrap_or_default().to_string()
    }

    /// Waits until the text of `css` satisfies `want`, saying `what` if it never does.
    fn wait_text(&self, what: &str, css: &str, want: impl Fn(&str) -> bool) {
        eventually(what, || {
            let text = self.text(css);
            want(&text).then_some(()).ok_or(text)
        });
    }

    /// Waits until `script` returns `want`, saying `what` if it never does.
    fn wait_js(&self, what: &str, script: &str, want: Value) {
        eventually(what, || {
            let got = self.js(script);
            (got == want).then_some(()).ok_or(got)
        });
    }

    fn click(&self, css: &str) {
        let el = self
            .run(self.client.find(Locator::Css(css)))
            .unwrap_or_else(|e| panic!("{css}: {e}"));
        self.run(el.click())
            .unwrap_or_else(|e| panic!("click {css}: {e}"));
    }

    fn goto(&self, url: &str) {
        self.run(self.client.goto(url))
            .unwrap_or_else(|e| panic!("{url}: {e}"));
    }

    /// The centre of an element, in viewport CSS pixels.
    fn centre(&self, css: &str) -> (i64, i64) {
        let script = format!(
            "const r = document.querySelector({css:?}).getBoundingClientRect(); \
             return [Math.round(r.x + r.width / 2), Math.round(r.y + r.height / 2)]"
        );
        let v = self.js(&script);
        (v[0].as_i64().unwrap_or(0), v[1].as_i64().unwrap_or(0))
    }

    /// A touch event through the DevTools protocol (`Input.dispatchTouchEvent`): the
    /// browser's own input path, with one finger's state kept between calls, as a person's.
    fn touch(&self, kind: &str, points: &[((i64, i64), u32)]) {
        let points: Vec<Value> = (points.iter())
            .map(|((x, y), id)| json!({ "x": x, "y": y, "id": id }))
            .collect();
        let cmd = Cdp(json!({
            "cmd": "Input.dispatchTouchEvent",
            "params": { "type": kind, "touchPoints": points },
        }));
        self.run(self.client.issue_cmd(cmd))
            .unwrap_or_else(|e| panic!("{kind}: {e}"));
    }

    fn finger_down(&self, at: (i64, i64)) {
        self.touch("touchStart", &[(at, 1)]);
        self.finger.set(Some(at));
    }

    /// Moves the finger through `path`, one touch event per point.
    fn finger_moves(&self, path: &[(i64, i64)]) {
        for &p in path {
            self.touch("touchMove", &[(p, 1)]);
            self.finger.set(Some(p));
        }
    }

    fn finger_up(&self) {
        self.touch("touchEnd", &[]);
        self.finger.set(None);
    }

    /// Taps `css` with a second finger while the first stays where it is (a thumb on a stick).
    fn tap_with_second_finger(&self, css: &str) {
        let held = self.finger.get().expect("a first finger down");
        let button = self.centre(css);
        self.touch("touchStart", &[(held, 1), (button, 2)]);
        // touchEnd lists the points that lift.
        self.touch("touchEnd", &[(button, 2)]);
    }

    fn screenshot(&self, name: &str) {
        let Some(dir) = std::env::var_os("ROVE_WEB_SHOTS") else {
            return;
        };
        let png = self.run(self.client.screenshot()).expect("screenshot");
        std::fs::write(Path::new(&dir).join(name), png).expect("write screenshot");
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let client = self.client.clone();
        let _ = self.rt.block_on(client.close());
        let _ = self.driver.kill();
        let _ = self.bridge.kill();
        let _ = self.driver.wait();
        let _ = self.bridge.wait();
    }
}

/// The web host: operator 20 (a desktop with no input of its own) serving phone 40, which
/// drives vehicle 100 while a finger is on a stick.
fn web_host(rig: &mut Rig, extra: &str, device: &str) -> usize {
    let config = rig.write(
        "web-host.toml",
        &format!(
            "[device]\nid = 20\nname = \"web-host\"\n[operator]\nlevel = \"stationary\"\n\
             device_class = \"desktop\"\n[web]\nlisten = \"127.0.0.1:{PORT}\"\n{extra}\n\
             [[web.device]]\nid = {PHONE}\ndrive = [{VEHICLE}]\n{device}\n"
        ),
    );
    rig.spawn(
        "operator-20",
        &["operator", "-c", config.to_str().expect("utf-8")],
    )
}

/// The pairing code the host logged last.
fn pairing_code(rig: &Rig) -> String {
    eventually("the host logs a pairing code", || {
        let log = rig.log_of("operator-20");
        log.rsplit("code=")
            .next()
            .filter(|_| log.contains("code="))
            .map(|s| s.chars().take(6).collect::<String>())
            .filter(|c| c.len() == 6 && c.chars().all(|d| d.is_ascii_digit()))
            .ok_or("no code yet")
    })
}

fn pair(browser: &Browser, rig: &Rig, name: &str) {
    browser.goto(&format!("https://127.0.0.1:{PORT}/"));
    let code = pairing_code(rig);
    let script = format!("document.getElementById('code').value = {code:?}; return 1");
    browser.js(&script);
    browser.click("#pair-button");
    eventually("the page is paired and connected", || {
        let me = browser.text("#me");
        if me.contains(&format!("{name} ({PHONE})")) {
            Ok(())
        } else {
            Err(format!(
                "#me is {me:?}, #pair-error {:?}",
                browser.text("#pair-error")
            ))
        }
    });
}

/// Outputs between two wall times, as (owner, action).
fn outputs_between(record: &Path, from_us: u64, to_us: u64) -> Vec<(Option<i64>, String)> {
    records(record)
        .into_iter()
        .filter(|o| o.wall_us >= from_us && o.wall_us <= to_us)
        .map(|o| (o.owner, o.action))
        .collect()
}

/// The first output after `since_us` where `owner` applies a throttle satisfying `want`.
fn wait_throttle(record: &Path, owner: i64, since_us: u64, want: impl Fn(i64) -> bool) -> u64 {
    eventually(&format!("{owner} applies the wanted throttle"), || {
        records(record)
            .into_iter()
            .find(|o| {
                o.wall_us >= since_us
                    && o.owner == Some(owner)
                    && o.action == "apply"
                    && o.throttle.is_some_and(&want)
            })
            .map(|o| o.wall_us)
            .ok_or_else(|| format!("last: {:?}", records(record).last()))
    })
}

/// A handover from `from` to `to` happened with no failsafe output between `from`'s last and
/// `to`'s first output after `since_us`.
/// Returns when `to` took over (its first output's wall time).
fn no_failsafe_gap(record: &Path, since_us: u64, to: i64) -> u64 {
    let first = wait_for_output(record, Some(to), since_us).expect("handover");
    let between = outputs_between(record, since_us, first.wall_us);
    assert!(
        between
            .iter()
            .all(|(owner, action)| owner.is_some() && action == "apply"),
        "a failsafe output during the handover to {to}: {between:?}"
    );
    first.wall_us
}

/// Asserts that `owner` applied nothing since `since_us` while the page sent 25 more frames
/// (half a second of its 50 Hz: the gateway has seen them), saying `why` otherwise.
fn assert_no_output_while_frames_flow(browser: &Browser, record: &Path, since_us: u64, why: &str) {
    let frames = browser
        .js("return window.rove.frames")
        .as_i64()
        .unwrap_or(0);
    eventually("the page's frames reach the gateway", || {
        let now = browser
            .js("return window.rove.frames")
            .as_i64()
            .unwrap_or(0);
        (now >= frames + 25).then_some(()).ok_or(now)
    });
    let moved: Vec<_> = records(record)
        .into_iter()
        .filter(|o| o.wall_us >= since_us && o.owner == Some(PHONE))
        .collect();
    assert!(moved.is_empty(), "{why}: {moved:?}");
}

#[test]
fn a_paired_phone_drives_hands_over_releases_when_hidden_or_closed_and_never_jumps() {
    let mut rig = Rig::new("web");
    let record = rig.vehicle(VEHICLE);
    // The laptop: the next operator, driving the whole time below the phone.
    rig.operator(LAPTOP, "stationary", "laptop", &[VEHICLE], 3000, "", &[]);
    web_host(&mut rig, "", "name = \"phone-web\"");
    wait_for_output(&record, Some(LAPTOP), 0).expect("the laptop drives first");

    let browser = Browser::start(&rig, PHONE_VIEW, 9515);
    pair(&browser, &rig, "phone-web");
    let vehicle = format!("({VEHICLE})");
    let what = "the page lists the vehicle, driven by the laptop";
    browser.wait_text(what, "#banner", |b| {
        b.contains("paused · input not live") && b.contains(&vehicle)
    });
    // One-handed on a 360 px phone: nothing scrolls sideways, the sticks sit in the lower half
    // (the thumb's reach), every button is at least 44 px tall.
    let layout = browser.js(
        "const s = document.getElementById('left').getBoundingClientRect(); \
         const small = [...document.querySelectorAll('button')].filter(b => b.offsetParent && \
           b.getBoundingClientRect().height < 44).length; \
         return [document.documentElement.scrollWidth, innerWidth, s.bottom, innerHeight, \
           s.top > innerHeight / 3, small]",
    );
    assert_eq!(
        layout[0], layout[1],
        "horizontal scroll on a phone: {layout}"
    );
    assert!(
        layout[2].as_f64() <= layout[3].as_f64(),
        "sticks below the screen: {layout}"
    );
    assert_eq!(layout[4], true, "sticks out of the thumb's reach: {layout}");
    assert_eq!(layout[5], 0, "buttons under 44 px: {layout}");
    browser.screenshot("web-phone-standby.png");

    // Drive: a finger on the left stick (it starts centred where it lands), then forward.
    let (x, y) = browser.centre("#left");
    let since = wall_us();
    browser.finger_down((x, y));
    wait_for_output(&record, Some(PHONE), since).expect("a finger on a stick drives");
    // Touch → vehicle output: one move at a time, forward then back, each stamped by the page
    // (the event's time, so WebDriver's own dispatch is not in it) and matched with the first
    // output that reflects it.
    let mut latencies = Vec::new();
    let mut page_part = Vec::new();
    for i in 0..20 {
        let (target, want): (i64, fn(i64) -> bool) = if i % 2 == 0 {
            (y - 90, |t| t > 10_000)
        } else {
            (y, |t| t.abs() < 2_000)
        };
        let before = wall_us();
        browser.finger_moves(&[(x, target)]);
        let applied = wait_throttle(&record, PHONE, before, want);
        let stamps = browser.js("return [window.rove.touchWallMs, window.rove.sentWallMs]");
        let touched = stamps[0].as_f64().unwrap_or(0.0);
        let sent = stamps[1].as_f64().unwrap_or(0.0);
        latencies.push(applied as f64 / 1000.0 - touched);
        page_part.push(sent - touched);
    }
    page_part.sort_by(f64::total_cmp);
    eprintln!(
        "of which in the browser (touch event → its frame sent by the page): p50 {:.1} ms",
        page_part[page_part.len() / 2]
    );
    latencies.sort_by(f64::total_cmp);
    eprintln!(
        "touch → vehicle output over {} moves: min {:.1} ms, p50 {:.1} ms, max {:.1} ms",
        latencies.len(),
        latencies[0],
        latencies[latencies.len() / 2],
        latencies[latencies.len() - 1]
    );
    assert!(
        latencies[0] > 0.0,
        "an output before its touch: {latencies:?}"
    );
    browser.finger_moves(&[(x, y - 90)]);
    browser.wait_text("the banner says the phone drives", "#banner", |b| {
        b.contains("YOU DRIVE")
    });
    browser.screenshot("web-phone-driving.png");

    // The finger lifts: released at once, the laptop drives with no failsafe between.
    let lifted = wall_us();
    browser.finger_up();
    no_failsafe_gap(&record, lifted, LAPTOP);

    // Silence: the page stops sending (a frozen tab, a dead radio) but the socket stays open.
    // After 200 ms the gateway releases; when frames come back (finger still centred), it
    // drives again.
    browser.finger_down((x, y));
    wait_for_output(&record, Some(PHONE), wall_us()).expect("the phone drives again");
    let muted = wall_us();
    browser.js(
        "window.realSend = WebSocket.prototype.send; WebSocket.prototype.send = () => {}; return 1",
    );
    no_failsafe_gap(&record, muted, LAPTOP);
    let silent_for = (wait_for_output(&record, Some(LAPTOP), muted)
        .expect("laptop")
        .wall_us
        - muted)
        / 1000;
    assert!(
        silent_for >= 150,
        "released after {silent_for} ms of silence, before the 200 ms"
    );
    assert!(
        rig.log_of("operator-20")
            .contains("no input from the browser for 200 ms")
    );
    let unmuted = wall_us();
    browser.js("WebSocket.prototype.send = window.realSend; return 1");
    wait_for_output(&record, Some(PHONE), unmuted).expect("frames again: the phone drives");
    browser.finger_up();

    // A request: another laptop asks; the page shows the consent prompt; accepted on the page.
    browser.finger_down((x, y));
    wait_for_output(&record, Some(PHONE), wall_us()).expect("the phone drives again");
    let asker = rig.operator(
        12,
        "remote",
        "desktop",
        &[],
        1500,
        "",
        &["--request", "100"],
    );
    eventually("the consent prompt shows, counting down", || {
        let shown = browser.js("return !document.getElementById('prompt').hidden");
        let text = browser.text("#prompt-text");
        let count = browser.text("#countdown");
        (shown == true && text.contains("(12)") && count.ends_with(" s)"))
            .then_some(())
            .ok_or(format!("{text:?} {count:?}"))
    });
    browser.screenshot("web-phone-request.png");
    let accepted = wall_us();
    browser.tap_with_second_finger("#accept");
    wait_for_output(&record, Some(12), accepted).expect("the asker drives after the accept");
    rig.procs[asker].stop();
    let back = wall_us();
    wait_for_output(&record, Some(PHONE), back).expect("the grant ends: the phone drives again");

    // Hidden (a locked screen, another app): released at once; the laptop takes over.
    let hidden = wall_us();
    browser
        .run(browser.client.minimize_window())
        .expect("minimize");
    let visibility = "return document.visibilityState";
    browser.wait_js("the page is hidden", visibility, json!("hidden"));
    no_failsafe_gap(&record, hidden, LAPTOP);
    let log = rig.log_of("operator-20");
    assert!(log.contains("page hidden"), "the release names why");

    // Shown again: a new touch (centred) drives.
    browser
        .run(
            browser
                .client
                .set_window_size(PHONE_VIEW.width, PHONE_VIEW.height),
        )
        .expect("restore");
    browser.wait_js("the page is visible again", visibility, json!("visible"));
    // The finger that was on the glass when the page hid has lifted (the page let go of it
    // already); then a new touch.
    browser.finger_up();
    let shown = wall_us();
    browser.finger_down((x, y));
    wait_for_output(&record, Some(PHONE), shown).expect("visible and touched: drives");

    // The link drops while the finger is forward: released at once; after reconnecting, the
    // pushed stick moves nothing until it comes back through centre.
    browser.finger_moves(&[(x, y - 45), (x, y - 90)]);
    wait_throttle(&record, PHONE, wall_us(), |t| t > 10_000);
    let dropped = wall_us();
    browser.js("window.rove.drop(); return 1");
    no_failsafe_gap(&record, dropped, LAPTOP);
    browser.wait_js(
        "the page reconnects",
        "return window.rove.connected",
        json!(true),
    );
    let reconnected = wall_us();
    let why = "moved from a pushed stick after reconnecting";
    assert_no_output_while_frames_flow(&browser, &record, reconnected, why);
    browser.wait_text("the page says why nothing moves", "#link", |t| {
        t.contains("sticks centred")
    });
    let centred = wall_us();
    browser.finger_moves(&[(x, y - 45), (x, y)]);
    let first = wait_for_output(&record, Some(PHONE), centred).expect("centred: drives again");
    assert!(
        first.throttle.is_some_and(|t| t.abs() < 2000),
        "the first output after the reconnect is centred: {first:?}"
    );

    // Closed: the tab goes; released, the laptop drives.
    let first_tab = browser.run(browser.client.window()).expect("window");
    let other = browser
        .run(browser.client.new_window(true))
        .expect("new tab");
    let closed = wall_us();
    browser.run(browser.client.close_window()).expect("close");
    // The page streams until the tab is really gone: the phone's outputs end at the handover.
    let laptop_again = no_failsafe_gap(&record, closed, LAPTOP);
    drop(first_tab);
    browser
        .run(browser.client.switch_to_window(other.handle))
        .expect("switch");

    // A wrong token is refused: the page asks to pair again.
    browser.goto(&format!("https://127.0.0.1:{PORT}/"));
    browser.js("localStorage.setItem('rove.token', 'deadbeef'); location.reload(); return 1");
    eventually("a wrong token is refused", || {
        let error = browser.text("#pair-error");
        let shown = browser.js("return !document.getElementById('pair').hidden");
        (shown == true && error.contains("unknown session token"))
            .then_some(())
            .ok_or(error)
    });
    let late: Vec<_> = (records(&record).into_iter())
        .filter(|o| o.owner == Some(PHONE) && o.wall_us > laptop_again)
        .collect();
    assert!(
        late.is_empty(),
        "the closed tab's phone drove again: {late:?}"
    );

    // No browser any more: after the linger, the device's participant leaves the fleet.
    eventually("the web device leaves after its browser", || {
        let log = rig.log_of("operator-20");
        log.contains("no browser for a while, the device leaves")
            .then_some(())
            .ok_or("not yet")
    });
    let row = Rig::device(&rig.status(), PHONE);
    assert!(
        row.as_ref().is_none_or(|d| d["online"] == false),
        "the web device is still listed online: {row:?}"
    );
}

/// One state on every console (issue 35): in each standing of the vehicle, the page's banner
/// and its list entry say the words the terminal console says (the `standing` event), and the
/// vehicle's health is in view: the autopilot's mode and battery, a low battery as a warning.
/// A MAVLink vehicle on the test autopilot, whose battery drains and which refuses AUTO.
#[test]
fn the_page_says_where_the_vehicle_stands_and_warns_of_a_low_battery() {
    let mut rig = Rig::new("web-standing");
    let _ap = rig.autopilot(&[
        "--connection",
        "udpin:127.0.0.1:14560",
        "--fail-modes",
        "10",
        "--battery-pct",
        "45",
        "--battery-drain",
        "1",
        "--duration",
        "300",
    ]);
    let record = rig.vehicle_with_output(
        VEHICLE,
        "[vehicle]\nbattery_low_pct = 30\n[output]\nadapter = \"mavlink\"\n\
         connection = \"udpout:127.0.0.1:14560\"\n",
    );
    web_host(
        &mut rig,
        "",
        "name = \"phone-web\"\ndevice_class = \"tablet\"",
    );
    // ROVE_WEB_VIEW=tablet: the same story on a tablet (screenshots for the docs).
    let tablet = std::env::var("ROVE_WEB_VIEW").is_ok_and(|v| v == "tablet");
    let (view, shots) = if tablet {
        (TABLET_VIEW, "tablet")
    } else {
        (PHONE_VIEW, "phone")
    };
    let browser = Browser::start(&rig, view, 9517);
    let shot = |name: &str| browser.screenshot(&format!("web-{shots}-{name}.png"));
    pair(&browser, &rig, "phone-web");
    // The banner names the vehicle and its standing; the list entry starts with the same words.
    let says = |what: &str, words: &str| {
        let banner = format!("v{VEHICLE} ({VEHICLE}): {words}");
        browser.wait_text(what, "#banner", |b| b == banner);
        let entry = browser.text(&format!("#devices li[data-id='{VEHICLE}'] .state"));
        assert!(entry.starts_with(words), "{what}: the list says {entry:?}");
    };
    says("nobody drives", "failsafe: stopped, nobody drives");
    browser.wait_text("the autopilot's mode and battery", "#health", |h| {
        h.contains("autopilot HOLD disarmed") && h.contains("battery 1")
    });
    shot("state-failsafe");

    let (x, y) = browser.centre("#left");
    let since = wall_us();
    browser.finger_down((x, y));
    wait_for_output(&record, Some(PHONE), since).expect("a finger on a stick drives");
    says("the phone drives", "YOU DRIVE");
    shot("state-driving");

    let strong = rig.operator(13, "mobile", "phone", &[VEHICLE], 0, "", &[]);
    says("a stronger operator takes over", "outranked by op13 (13)");
    shot("state-outranked");
    browser.finger_up();
    says(
        "the finger lifts",
        "paused · input not live · owner op13 (13)",
    );
    shot("state-paused");
    rig.procs[strong].crash();
    says(
        "the stronger one is gone",
        "failsafe: stopped, nobody drives",
    );

    // Driving again, then AUTO, which the autopilot refuses: the vehicle holds.
    browser.finger_down((x, y));
    says("the phone drives again", "YOU DRIVE");
    for _ in 0..2 {
        browser.tap_with_second_finger("#modes button[data-mode='auto']");
    }
    says(
        "the autopilot refused AUTO",
        &format!("held by autopilot · owner you ({PHONE})"),
    );
    shot("state-held");
    // `rove status` says the same: held, with the autopilot's own mode (not the one asked for).
    let row = rig.device_when("rove status says held", VEHICLE, |d| {
        d["standing"] == "held"
    });
    assert_eq!(row["failsafe"], true, "{row}");
    assert_eq!(row["controller_id"], PHONE, "{row}");
    assert_eq!(row["health"]["held"], true, "{row}");
    assert_ne!(row["health"]["autopilot_mode"], "AUTO", "{row}");
    eprintln!("rove status while held: {row}");

    // The battery drains below 30 %: a warning, whatever else the page shows.
    browser.wait_text("a low battery", "#warn", |w| {
        w.starts_with(&format!("LOW BATTERY v{VEHICLE} ({VEHICLE}): 1")) && w.ends_with('%')
    });
    let entry = browser.text(&format!("#devices li[data-id='{VEHICLE}'] .state"));
    assert!(entry.contains(" · LOW 1"), "{entry}");
    shot("low-battery");
    browser.finger_up();
}

#[test]
fn a_tablet_lays_out_side_by_side_drives_with_a_gamepad_and_its_expired_session_is_refused() {
    let mut rig = Rig::new("web-tablet");
    let record = rig.vehicle(VEHICLE);
    web_host(
        &mut rig,
        "session_s = 3",
        "name = \"tablet-web\"\ndevice_class = \"tablet\"",
    );
    let browser = Browser::start(&rig, TABLET_VIEW, 9516);
    // A wrong code is refused on the page.
    browser.goto(&format!("https://127.0.0.1:{PORT}/"));
    let right = pairing_code(&rig);
    let wrong: String = (right.chars())
        .map(|d| char::from(b'0' + (d as u8 - b'0' + 1) % 10))
        .collect();
    browser.js(&format!(
        "document.getElementById('code').value = {wrong:?}; return 1"
    ));
    browser.click("#pair-button");
    browser.wait_text("a wrong code is refused", "#pair-error", |e| {
        e.contains("wrong pairing code")
    });
    pair(&browser, &rig, "tablet-web");
    let paired_at = std::time::Instant::now();
    // Landscape tablet: the panel beside the sticks, nothing scrolls.
    let layout = browser.js(
        "const p = document.getElementById('panel').getBoundingClientRect(); \
         const s = document.getElementById('sticks').getBoundingClientRect(); \
         return [p.right <= s.left, document.documentElement.scrollHeight <= innerHeight, \
           document.documentElement.scrollWidth <= innerWidth]",
    );
    assert_eq!(layout, json!([true, true, true]), "tablet layout");
    let vehicle = format!("({VEHICLE})");
    browser.wait_text("the page lists the vehicle", "#banner", |b| {
        b.contains(&vehicle)
    });
    browser.screenshot("web-tablet.png");

    // A gamepad through the Gamepad API (chromium has no virtual gamepad: the page's
    // `navigator.getGamepads` is replaced by one whose state the test sets). The shoulder
    // button is the deadman; a stick pushed when it is pressed moves nothing until centred.
    browser.js("window.pad = { id: 'test pad', axes: [0, 0, 0, 0], \
           buttons: Array.from({ length: 8 }, () => ({ pressed: false })) }; \
         navigator.getGamepads = () => [window.pad]; return 1");
    let pad = |script: &str| browser.js(&format!("{script}; return 1"));
    let pressed = wall_us();
    pad("pad.axes[1] = -0.8; pad.buttons[5].pressed = true");
    let why = "a pushed pad drove when its deadman was pressed";
    assert_no_output_while_frames_flow(&browser, &record, pressed, why);
    let centred = wall_us();
    pad("pad.axes[1] = 0");
    let first = wait_for_output(&record, Some(PHONE), centred).expect("centred: the pad drives");
    assert!(first.throttle.is_some_and(|t| t.abs() < 2000), "{first:?}");
    let pushed = wall_us();
    pad("pad.axes[1] = -0.8");
    wait_throttle(&record, PHONE, pushed, |t| t > 20_000);
    let let_go = wall_us();
    pad("pad.buttons[5].pressed = false");
    wait_for_output(&record, None, let_go).expect("deadman released: the vehicle's failsafe");
    // The session lasts 3 s: after it, the same token no longer connects.
    let token = browser.js("return localStorage.getItem('rove.token')");
    assert!(token.as_str().is_some_and(|t| t.len() == 32), "{token}");
    while paired_at.elapsed() < Duration::from_secs(4) {
        // The session's end is the thing under test: time must pass.
        std::thread::sleep(Duration::from_millis(100));
    }
    browser.js("location.reload(); return 1");
    browser.wait_text("an expired token is refused", "#pair-error", |e| {
        e.contains("expired")
    });
}

#[test]
fn in_a_secured_fleet_a_paired_phone_drives_as_its_own_certified_participant() {
    let mut rig = Rig::new("web-secure");
    let fleet = rig.fleet(&[VEHICLE, 20, PHONE]).expect("fleet");
    let web = rove_gateway::certs::web(
        &fleet,
        &["127.0.0.1".to_string()],
        rove_gateway::certs::Lifetime::DEVICE,
    )
    .expect("web cert");
    let security = |id| rove_tools::harness::security_toml(Some(&fleet), id);
    let output = format!("{}[output]\nadapter = \"sim\"\n", security(VEHICLE));
    let record = rig.vehicle_with_output(VEHICLE, &output);
    let device_dir = fleet.join(PHONE.to_string());
    web_host(
        &mut rig,
        &format!(
            "certificate = {:?}\nkey = {:?}\n{}",
            web.join("cert.pem"),
            web.join("key.pem"),
            security(20)
        ),
        &format!("name = \"phone-web\"\nsecurity = {device_dir:?}"),
    );
    let browser = Browser::start(&rig, PHONE_VIEW, 9517);
    pair(&browser, &rig, "phone-web");
    let log = rig.log_of("operator-20");
    assert!(
        log.contains("certificate=loaded from") && log.contains("web-127.0.0.1"),
        "the page is served with the fleet's certificate"
    );
    let at = browser.centre("#left");
    let touched = wall_us();
    browser.finger_down(at);
    wait_for_output(&record, Some(PHONE), touched).expect("the secured phone drives");
    let lifted = wall_us();
    browser.finger_up();
    wait_for_output(&record, None, lifted).expect("lifted: the vehicle's failsafe");
}
