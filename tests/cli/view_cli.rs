//! `prism view` as a person uses it: the built binary serves a tiny teacher (ndarray, 32 px)
//! and a real headless Chromium (the distribution's package) loads the page, moves the camera
//! with key presses and a drag, and goes live with Chromium's fake camera. Beside the browser,
//! the API is checked directly: a frame equals `prism infer`'s view at the same camera, bad
//! uploads are refused with a message while the server keeps serving, and SIGINT stops it
//! cleanly.
//!
//! Chromium is found as `chromium` or `chromium-browser` on the PATH, or at `PRISM_CHROMIUM`;
//! without it the test fails saying so (`.ci/run` installs it).

use crate::browser;
use crate::common;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use prism_train::infer::{Sweep, sweep_views, view_file_name};
use prism_train::{RunOptions, TeacherTask, train};

use common::{prism_with_cache, s, scratch, success, tiny_at_32px};

/// A tiny teacher trained 4 steps on the tiny dataset in the private cache `cache`: the run
/// folder and the dataset folder.
fn tiny_teacher(cache: &Path, dir: &Path) -> (PathBuf, PathBuf) {
    let mut config = tiny_at_32px();
    config.train.steps = 4;
    config.train.checkpoint_every = 4;
    let data = prism_synth::ensure_synthetic_dataset_in(cache, &config.data, false).unwrap();
    let run = dir.join("teacher");
    let options = RunOptions::new(&run, &data, prism_core::BackendKind::Ndarray);
    let task = TeacherTask {
        lpips_weights: None,
    };
    train(&config, &task, &options).unwrap();
    (run, data)
}

/// `prism view` serving `run` on a free loopback port, and the address it announced.
fn start_view(cache: &Path, run: &Path, data: &Path) -> (Child, String) {
    browser::start_viewer(
        prism_with_cache(
            cache,
            &[
                "view",
                "--checkpoint",
                s(run),
                "--data",
                s(data),
                "--listen",
                "127.0.0.1:0",
                "--backend",
                "ndarray",
            ],
        )
        .stderr(Stdio::piped()),
    )
}

/// One HTTP/1.1 request to `address`: the status and the body.
fn http(address: &str, method: &str, path: &str, body: &[u8]) -> (u16, Vec<u8>) {
    let mut stream = TcpStream::connect(address).unwrap();
    stream
        .set_read_timeout(Some(Duration::from_secs(120)))
        .unwrap();
    write!(
        stream,
        "{method} {path} HTTP/1.1\r\nHost: {address}\r\nContent-Length: {}\r\nConnection: \
         close\r\n\r\n",
        body.len()
    )
    .unwrap();
    stream.write_all(body).unwrap();
    let mut answer = Vec::new();
    stream.read_to_end(&mut answer).unwrap();
    let split = answer
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("an HTTP answer");
    let head = String::from_utf8_lossy(&answer[..split]).to_string();
    let status = head.split(' ').nth(1).unwrap().parse().unwrap();
    assert!(
        !head
            .to_ascii_lowercase()
            .contains("transfer-encoding: chunked"),
        "{head}"
    );
    (status, answer[split + 4..].to_vec())
}

fn json(bytes: &[u8]) -> serde_json::Value {
    serde_json::from_slice(bytes)
        .unwrap_or_else(|e| panic!("{e}: {}", String::from_utf8_lossy(bytes)))
}

#[test]
fn the_viewer_answers_the_browser_like_infer_and_stops_on_sigint() {
    let dir = scratch("view");
    let cache = dir.join("cache");
    let (run, data) = tiny_teacher(&cache, &dir);
    let (mut child, address) = start_view(&cache, &run, &data);

    // The API: one model, the held-out person, the protocol's range.
    let (status, body) = http(&address, "GET", "/api/info", b"");
    assert_eq!(status, 200);
    let info = json(&body);
    assert_eq!(info["models"].as_array().unwrap().len(), 1);
    assert_eq!(info["people"].as_array().unwrap().len(), 1, "{info}");
    assert_eq!(info["max_angle_deg"], 30.0);

    // A bad upload gets a message, and the server keeps serving.
    let (status, body) = http(&address, "POST", "/api/photo", b"not an image at all");
    assert_eq!(status, 400);
    let refusal = json(&body)["error"].as_str().unwrap().to_string();
    assert!(refusal.contains("not a png or jpeg image"), "{refusal}");

    // A photo: the frame at yaw +10 is `prism infer`'s view at that camera.
    let person = info["people"][0].as_str().unwrap();
    let photo = data.join(person).join("rgb/000.png");
    let (status, _) = http(
        &address,
        "POST",
        "/api/photo",
        &std::fs::read(&photo).unwrap(),
    );
    assert_eq!(status, 200);
    let (status, png) = http(&address, "GET", "/api/view.png?yaw=10&pitch=0", b"");
    assert_eq!(status, 200);
    let served = image::load_from_memory(&png).unwrap().to_rgb8();
    let infer_dir = dir.join("infer");
    success(prism_with_cache(
        &cache,
        &[
            "infer",
            "--checkpoint",
            s(&run),
            "--image",
            s(&photo),
            "--out",
            s(&infer_dir),
            "--sweep",
            "yaw",
            "--backend",
            "ndarray",
            "--quiet",
        ],
    ));
    let view = sweep_views(Sweep::Yaw, 10.0, 30.0)
        .into_iter()
        .find(|v| v.yaw_deg == 10.0)
        .unwrap();
    let inferred = image::open(infer_dir.join(view_file_name(&view)))
        .unwrap()
        .to_rgb8();
    assert_eq!(served.dimensions(), inferred.dimensions());
    let worst = served
        .as_raw()
        .iter()
        .zip(inferred.as_raw())
        .map(|(a, b)| a.abs_diff(*b))
        .max()
        .unwrap();
    assert!(
        worst <= 1,
        "the served frame differs from infer's by {worst} levels"
    );
    let (status, ply) = http(&address, "GET", "/api/gaussians.ply", b"");
    assert_eq!(status, 200);
    assert!(ply.starts_with(b"ply\n"), "a 3DGS PLY");

    // The browser: the held-out person with its ground truth, moved by the arrow keys.
    let mut browser = browser::Browser::launch(&dir.join("chromium"));
    let page = browser.open(&format!("http://{address}/"));
    let shown = |b: &mut browser::Browser| b.eval(&page, "document.getElementById('nvs').src");
    browser.wait(
        &page,
        "document.getElementById('nvs').src.startsWith('data:image/png')",
    );
    browser.eval(
        &page,
        "const p = document.getElementById('person'); p.value = '0'; \
         p.dispatchEvent(new Event('change'))",
    );
    browser.wait(
        &page,
        "document.getElementById('truth').src.startsWith('data:image/png')",
    );
    browser.wait(
        &page,
        "document.getElementById('psnr').textContent.includes('dB')",
    );
    let before = shown(&mut browser);
    let yaw_before = browser.eval(&page, "document.getElementById('yaw').textContent");
    browser.eval(&page, "document.getElementById('stage').focus()");
    for _ in 0..8 {
        browser.key(&page, "ArrowRight", 39);
    }
    browser.wait(
        &page,
        &format!("document.getElementById('yaw').textContent !== {yaw_before}"),
    );
    browser.wait(
        &page,
        &format!("document.getElementById('nvs').src !== {before}"),
    );
    // A drag to the left turns the camera back while the mouse moves.
    let yaw_keyed = browser.eval(&page, "document.getElementById('yaw').textContent");
    let (x, y) = browser.center(&page, "stage");
    browser.mouse(&page, "mousePressed", x, y);
    for step in 1..=6 {
        browser.mouse(&page, "mouseMoved", x - 10.0 * f64::from(step), y);
    }
    browser.mouse(&page, "mouseReleased", x - 60.0, y);
    browser.wait(
        &page,
        &format!("+document.getElementById('yaw').textContent < +{yaw_keyed}"),
    );
    let fps = browser.eval(&page, "document.getElementById('fps').textContent");
    assert!(
        fps.trim_matches('"').parse::<f64>().unwrap() > 0.0,
        "FPS shown: {fps}"
    );
    if let Some(out) = std::env::var_os("PRISM_VIEW_SCREENSHOT") {
        browser.screenshot(&page, Path::new(&out));
    }

    // Live: Chromium's fake camera streams frames, each answered with a novel view.
    browser.eval(&page, "document.getElementById('live').click()");
    browser.wait(
        &page,
        "+document.getElementById('live-count').textContent >= 3",
    );
    browser.eval(&page, "document.getElementById('live').click()");
    drop(browser);

    // SIGINT stops the server cleanly.
    let pid = child.id().to_string();
    assert!(
        Command::new("kill")
            .args(["-INT", &pid])
            .status()
            .unwrap()
            .success()
    );
    let started = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "still serving after SIGINT"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut stderr = String::new();
    child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    assert!(status.success(), "{status}: {stderr}");
    assert!(stderr.contains("prism view: stopped"), "{stderr}");
    let _ = std::fs::remove_dir_all(dir);
}
