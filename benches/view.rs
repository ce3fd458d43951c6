//! The viewer's latency as a person feels it:
//! `cargo bench --workspace --bench view -- --checkpoint RUN [--model student|teacher]
//! [--backend flex] [--data DIR] [--presses 20] [--drag-seconds 6]`.
//!
//! Times, in one run on one machine:
//! - `prism bench`'s forward time of the same model (config `RUN/config.toml`, batch 1, the
//!   model's resolution, median after warm-up): what the network alone costs;
//! - `prism view --checkpoint RUN` in a headless Chromium (the end-to-end test's browser,
//!   `tests/cli/browser.rs`) opened at the URL it prints (with its token), on the page's
//!   default input (the first held-out person):
//!   - the server's time per frame (forward, 3DGS render, read back), as the page shows it;
//!   - from an arrow-key press to the new frame decoded in the page, one press at a time;
//!   - the frames shown per second while the mouse drags at 60 events per second.
//!
//! The latency less the forward time is what the viewer adds: on the server the 3DGS head's
//! render (which the page shows and `prism bench` leaves out) and the read back, then the PNG and
//! JSON encoding, the HTTP round trip and the page's decode. The last part, the latency of each
//! press less its own frame's server time, is printed on its own: it does not move with the
//! noise of the model's time on a busy CPU.

#[allow(dead_code)] // shared with the end-to-end test, which uses all of it
#[path = "../tests/cli/browser.rs"]
mod browser;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use browser::Browser;

/// What to measure: the bench's command-line arguments.
struct Args {
    checkpoint: PathBuf,
    model: String,
    backend: String,
    data: Option<PathBuf>,
    presses: usize,
    drag_seconds: f64,
}

impl Args {
    fn parse() -> Self {
        let mut args = Self {
            checkpoint: PathBuf::new(),
            model: "student".into(),
            backend: "flex".into(),
            data: None,
            presses: 20,
            drag_seconds: 6.0,
        };
        let mut given = std::env::args().skip(1).filter(|a| a != "--bench");
        while let Some(flag) = given.next() {
            let mut value = || {
                given
                    .next()
                    .unwrap_or_else(|| panic!("{flag} needs a value"))
            };
            match flag.as_str() {
                "--checkpoint" => args.checkpoint = value().into(),
                "--model" => args.model = value(),
                "--backend" => args.backend = value(),
                "--data" => args.data = Some(value().into()),
                "--presses" => args.presses = value().parse().expect("--presses: a count"),
                "--drag-seconds" => {
                    args.drag_seconds = value().parse().expect("--drag-seconds: seconds");
                }
                other => {
                    panic!("unknown argument {other} (see the doc comment of benches/view.rs)")
                }
            }
        }
        assert!(
            args.checkpoint.join("config.toml").is_file(),
            "--checkpoint RUN: a run folder with its config.toml (got {:?})",
            args.checkpoint
        );
        args
    }
}

/// The `prism` binary of this build.
fn prism() -> Command {
    Command::new(env!("CARGO_BIN_EXE_prism"))
}

/// `prism bench`'s forward time of `args.model` in milliseconds (median of its timed runs).
fn bench_forward_ms(args: &Args, scratch: &Path) -> f64 {
    let json = scratch.join("bench.json");
    let config = args.checkpoint.join("config.toml");
    let status = prism()
        .args(["bench", "--config"])
        .arg(&config)
        .args(["--models", &args.model, "--backend", &args.backend])
        .args(["--train-steps", "0", "--iters", "20", "--json"])
        .arg(&json)
        .stdout(Stdio::null())
        .status()
        .expect("running prism bench");
    assert!(status.success(), "prism bench failed: {status}");
    let rows: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    rows["rows"][0]["ms"].as_f64().expect("a forward row")
}

/// `prism view` serving the run on a free loopback port.
fn start_view(args: &Args) -> browser::Viewer {
    let mut command = prism();
    command
        .arg("view")
        .arg("--checkpoint")
        .arg(&args.checkpoint)
        .args(["--listen", "127.0.0.1:0", "--backend", &args.backend]);
    if let Some(data) = &args.data {
        command.arg("--data").arg(data);
    }
    browser::start_viewer(&mut command)
}

/// Installed in the page: each frame `show`n is timed when its NVS image is decoded and the
/// next animation frame starts (when it can be on screen), and each key press is timed as the
/// page receives it.
const PROBE: &str = "
window.probe = { frames: [], key: 0 };
const shownBefore = show;
show = function (frame) {
  shownBefore(frame);
  document.getElementById('nvs').decode().then(() => requestAnimationFrame(() =>
    window.probe.frames.push({ at: performance.now(), server_ms: frame.server_ms })));
};
document.getElementById('stage').addEventListener('keydown',
  () => { window.probe.key = performance.now(); }, true);
";

/// The frames the probe has timed: (shown at, server milliseconds).
fn frames(browser: &mut Browser, page: &str) -> Vec<(f64, f64)> {
    let text = browser.eval(page, "window.probe.frames.map((f) => [f.at, f.server_ms])");
    serde_json::from_str(&text).unwrap()
}

fn median(values: &mut [f64]) -> f64 {
    quantile(values, 0.5)
}

/// The value at fraction `q` of the sorted `values` (the nearest rank).
fn quantile(values: &mut [f64], q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * q).round() as usize]
}

/// Milliseconds from each key press to its frame, and that frame's server time, one press at a
/// time (yaw out to the right, then back).
fn key_latencies(browser: &mut Browser, page: &str, presses: usize) -> Vec<(f64, f64)> {
    browser.eval(page, "document.getElementById('stage').focus()");
    let mut latencies = Vec::with_capacity(presses);
    for press in 0..presses {
        let (key, code) = if press < presses / 2 {
            ("ArrowRight", 39)
        } else {
            ("ArrowLeft", 37)
        };
        let count = frames(browser, page).len();
        browser.key(page, key, code);
        browser.wait(page, &format!("window.probe.frames.length > {count}"));
        let key_at: f64 = browser.eval(page, "window.probe.key").parse().unwrap();
        let (shown, server) = frames(browser, page)[count];
        latencies.push((shown - key_at, server));
        std::thread::sleep(Duration::from_millis(300));
    }
    latencies
}

/// Frames shown per second, and their server times, while the mouse drags the camera for
/// `seconds` (a mouse move every 1/60 s, yaw swinging +-25 degrees).
fn drag(browser: &mut Browser, page: &str, seconds: f64) -> (f64, Vec<f64>) {
    let (x, y) = browser.center(page, "stage");
    browser.mouse(page, "mousePressed", x, y);
    let first = frames(browser, page).len();
    let start_ms: f64 = browser.eval(page, "performance.now()").parse().unwrap();
    let start = Instant::now();
    let period = Duration::from_secs_f64(1.0 / 60.0);
    let mut moves = 0u32;
    while start.elapsed().as_secs_f64() < seconds {
        moves += 1;
        // A triangle wave of 100 px (25 degrees at the page's 0.25 degree per pixel), 2 s long.
        let phase = (f64::from(moves) / 120.0).fract();
        let offset = 100.0 * (1.0 - (4.0 * phase - 2.0).abs()).clamp(-1.0, 1.0);
        browser.mouse(page, "mouseMoved", x + offset, y);
        if let Some(rest) = (period * moves).checked_sub(start.elapsed()) {
            std::thread::sleep(rest);
        }
    }
    let end_ms: f64 = browser.eval(page, "performance.now()").parse().unwrap();
    browser.mouse(page, "mouseReleased", x, y);
    let during: Vec<(f64, f64)> = frames(browser, page)[first..]
        .iter()
        .copied()
        .filter(|(at, _)| *at <= end_ms)
        .collect();
    let fps = during.len() as f64 * 1e3 / (end_ms - start_ms);
    (fps, during.into_iter().map(|(_, server)| server).collect())
}

fn main() {
    let args = Args::parse();
    let scratch = tempfile::tempdir().unwrap();
    let forward_ms = bench_forward_ms(&args, scratch.path());

    let server = start_view(&args);
    let mut browser = Browser::launch(&scratch.path().join("chromium"));
    let page = browser.open(&server.url);
    browser.wait(
        &page,
        "document.getElementById('nvs').src.startsWith('data:image/png')",
    );
    browser.eval(&page, PROBE);
    let pressed = key_latencies(&mut browser, &page, args.presses);
    let mut latencies: Vec<f64> = pressed.iter().map(|(latency, _)| *latency).collect();
    let mut beyond_server: Vec<f64> = pressed.iter().map(|(l, server)| l - server).collect();
    std::thread::sleep(Duration::from_millis(500));
    let (drag_fps, mut drag_server_ms) = drag(&mut browser, &page, args.drag_seconds);
    let mut server_ms: Vec<f64> = frames(&mut browser, &page)
        .into_iter()
        .map(|(_, server)| server)
        .collect();
    drop(browser);
    drop(server);

    println!(
        "| `{}` {} on {} | ms | frames / s |",
        args.checkpoint.display(),
        args.model,
        args.backend
    );
    println!("|---|---|---|");
    println!(
        "| `prism bench` forward (median) | {forward_ms:.1} | {:.1} |",
        1e3 / forward_ms
    );
    let server = median(&mut server_ms);
    println!(
        "| viewer: server time per frame (median of {}) | {server:.1} | {:.1} |",
        server_ms.len(),
        1e3 / server
    );
    let (p50, p90) = (median(&mut latencies), quantile(&mut latencies, 0.9));
    println!(
        "| viewer: key press to frame shown (median of {}; p90 {p90:.1} ms) | {p50:.1} | {:.1} |",
        latencies.len(),
        1e3 / p50
    );
    println!(
        "| viewer: while dragging {:.0} s (server median {:.1} ms over {} frames) | {:.1} | {drag_fps:.1} |",
        args.drag_seconds,
        median(&mut drag_server_ms),
        drag_server_ms.len(),
        1e3 / drag_fps
    );
    println!(
        "key press to frame, less the forward pass: {:.1} ms; less the frame's own server time \
         (encoding, HTTP, the page's decode): {:.1} ms (medians)",
        p50 - forward_ms,
        median(&mut beyond_server)
    );
}
