//! `prism view` as a person uses it: the built binary serves a tiny teacher (ndarray, 32 px)
//! and a real headless Chromium (the distribution's package) loads the page, moves the camera
//! with key presses and goes live with Chromium's fake camera. Beside the browser, the API is
//! checked directly: a frame equals `prism infer`'s view at the same camera, bad uploads are
//! refused with a message while the server keeps serving, and SIGINT stops it cleanly.
//!
//! Chromium is found as `chromium` or `chromium-browser` on the PATH, or at `PRISM_CHROMIUM`;
//! without it the test fails saying so (`.ci/run` installs it).

use crate::common;

use std::io::{BufRead, BufReader, Read, Write};
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
    let mut child = prism_with_cache(
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
    .stdout(Stdio::piped())
    .stderr(Stdio::piped())
    .spawn()
    .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let address = line
        .split("http://")
        .nth(1)
        .and_then(|rest| rest.split('/').next())
        .unwrap_or_else(|| panic!("no address announced: {line:?}"))
        .to_string();
    (child, address)
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

/// A headless Chromium driven over the DevTools protocol (one WebSocket, JSON messages).
mod browser {
    use std::io::{BufRead, BufReader};
    use std::net::TcpStream;
    use std::path::Path;
    use std::process::{Child, Command, Stdio};
    use std::time::{Duration, Instant};

    use base64::Engine as _;
    use serde_json::{Value, json};
    use tungstenite::stream::MaybeTlsStream;
    use tungstenite::{Message, WebSocket};

    /// The Chromium of this machine: `PRISM_CHROMIUM`, else `chromium` or `chromium-browser`
    /// on the PATH.
    fn executable() -> String {
        if let Some(path) = std::env::var_os("PRISM_CHROMIUM") {
            return path.to_string_lossy().into_owned();
        }
        for name in ["chromium", "chromium-browser"] {
            let found = Command::new(name)
                .arg("--version")
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success());
            if found {
                return name.into();
            }
        }
        panic!(
            "Chromium is not installed (apt-get install chromium, or set PRISM_CHROMIUM): the \
             viewer's browser test cannot run"
        );
    }

    /// A running browser and its DevTools connection.
    pub struct Browser {
        child: Child,
        socket: WebSocket<MaybeTlsStream<TcpStream>>,
        next: u64,
    }

    impl Browser {
        /// Starts headless Chromium with a fresh profile in `profile` and a fake camera.
        pub fn launch(profile: &Path) -> Self {
            let mut child = Command::new(executable())
                .args([
                    "--headless",
                    "--no-sandbox",
                    "--disable-gpu",
                    "--disable-dev-shm-usage",
                    "--no-first-run",
                    "--disable-background-networking",
                    "--disable-component-update",
                    "--disable-sync",
                    "--use-fake-device-for-media-stream",
                    "--use-fake-ui-for-media-stream",
                    "--remote-debugging-port=0",
                    "--window-size=1200,800",
                ])
                .arg(format!("--user-data-dir={}", profile.display()))
                .arg("about:blank")
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .expect("starting Chromium");
            let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
            let url = loop {
                let line = lines
                    .next()
                    .expect("Chromium exited before opening DevTools")
                    .unwrap();
                if let Some(at) = line.find("ws://") {
                    break line[at..].trim().to_string();
                }
            };
            // Keep reading Chromium's log so that it never blocks on a full pipe.
            std::thread::spawn(move || lines.for_each(drop));
            let (socket, _) = tungstenite::connect(url.as_str()).expect("DevTools WebSocket");
            Self {
                child,
                socket,
                next: 0,
            }
        }

        /// Sends a DevTools command (to a page's session, or to the browser) and returns its
        /// result, skipping the events in between.
        pub fn call(&mut self, session: Option<&str>, method: &str, params: Value) -> Value {
            self.next += 1;
            let id = self.next;
            let mut message = json!({ "id": id, "method": method, "params": params });
            if let Some(session) = session {
                message["sessionId"] = json!(session);
            }
            self.socket
                .send(Message::text(message.to_string()))
                .expect("DevTools send");
            loop {
                let Message::Text(text) = self.socket.read().expect("DevTools read") else {
                    continue;
                };
                let answer: Value = serde_json::from_str(&text).unwrap();
                if answer["id"] == id {
                    assert!(answer.get("error").is_none(), "{method}: {answer}");
                    return answer["result"].clone();
                }
            }
        }

        /// Opens `url` in a new tab; returns the tab's session.
        pub fn open(&mut self, url: &str) -> String {
            let target = self.call(None, "Target.createTarget", json!({ "url": url }));
            let attached = self.call(
                None,
                "Target.attachToTarget",
                json!({ "targetId": target["targetId"], "flatten": true }),
            );
            attached["sessionId"].as_str().unwrap().to_string()
        }

        /// The value of the JavaScript `expression` in the page, as JSON text.
        pub fn eval(&mut self, page: &str, expression: &str) -> String {
            let result = self.call(
                Some(page),
                "Runtime.evaluate",
                json!({ "expression": expression, "returnByValue": true }),
            );
            result["result"]["value"].to_string()
        }

        /// Waits (up to two minutes) until `condition` is true in the page.
        pub fn wait(&mut self, page: &str, condition: &str) {
            let start = Instant::now();
            while self.eval(page, condition) != "true" {
                let message = self.eval(page, "document.getElementById('message').textContent");
                assert!(
                    start.elapsed() < Duration::from_secs(120),
                    "timed out waiting for `{condition}` (page says {message})"
                );
                std::thread::sleep(Duration::from_millis(100));
            }
        }

        /// Presses and releases `key` (with its Windows key code) in the focused element.
        pub fn key(&mut self, page: &str, key: &str, code: u32) {
            for kind in ["keyDown", "keyUp"] {
                self.call(
                    Some(page),
                    "Input.dispatchKeyEvent",
                    json!({ "type": kind, "key": key, "code": key,
                            "windowsVirtualKeyCode": code }),
                );
            }
        }

        /// Saves a PNG screenshot of the page to `path`.
        pub fn screenshot(&mut self, page: &str, path: &Path) {
            let shot = self.call(Some(page), "Page.captureScreenshot", json!({}));
            let png = base64::engine::general_purpose::STANDARD
                .decode(shot["data"].as_str().unwrap())
                .unwrap();
            std::fs::write(path, png).unwrap();
        }
    }

    impl Drop for Browser {
        fn drop(&mut self) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
