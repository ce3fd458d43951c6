//! A headless Chromium driven over the DevTools protocol (one WebSocket, JSON messages): what
//! the viewer's browser test and its latency benchmark (`benches/view.rs`, which includes this
//! file) use to start `prism view`, load its page at the URL it prints, press keys, drag the
//! mouse and read the page's state.
//!
//! Chromium is found as `chromium` or `chromium-browser` on the PATH, or at `PRISM_CHROMIUM`.

use std::io::{BufRead, BufReader};
use std::net::TcpStream;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine as _;
use serde_json::{Value, json};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

/// A started `prism view`; killed when dropped (a failed test leaves no server behind).
pub struct Viewer {
    /// The process.
    pub child: Child,
    /// The page's URL it printed, with its token.
    pub url: String,
}

impl Viewer {
    /// The address it listens on, `HOST:PORT`.
    pub fn address(&self) -> &str {
        let rest = self.url.trim_start_matches("http://");
        rest.split('/').next().unwrap()
    }

    /// The port it listens on.
    pub fn port(&self) -> u16 {
        let port = self.address().rsplit(':').next().unwrap();
        port.parse().unwrap()
    }

    /// The token of its URL (empty if none).
    pub fn token(&self) -> &str {
        self.url.split_once("token=").map_or("", |(_, token)| token)
    }
}

impl Drop for Viewer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts `prism view` (`command`, with its arguments, listening on port 0), once it has
/// printed its URL on its first line of stdout.
pub fn start_viewer(command: &mut Command) -> Viewer {
    let mut child = command
        .stdout(Stdio::piped())
        .spawn()
        .expect("starting prism view");
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let url = line
        .split_whitespace()
        .find(|word| word.starts_with("http://"))
        .unwrap_or_else(|| panic!("prism view announced no URL: {line:?}"))
        .to_string();
    Viewer { child, url }
}

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

    /// The centre of the element `id` in the page's CSS pixels (where a mouse event lands on it).
    pub fn center(&mut self, page: &str, id: &str) -> (f64, f64) {
        let rect = self.eval(
            page,
            &format!(
                "(() => {{ const r = document.getElementById('{id}').getBoundingClientRect(); \
                 return [r.x + r.width / 2, r.y + r.height / 2]; }})()"
            ),
        );
        let at: Vec<f64> = serde_json::from_str(&rect).unwrap();
        (at[0], at[1])
    }

    /// A left-button mouse event at (`x`, `y`) in CSS pixels: `kind` is `mousePressed`,
    /// `mouseMoved` (with the button held) or `mouseReleased`.
    pub fn mouse(&mut self, page: &str, kind: &str, x: f64, y: f64) {
        self.call(
            Some(page),
            "Input.dispatchMouseEvent",
            json!({ "type": kind, "x": x, "y": y, "button": "left", "buttons": 1,
                    "clickCount": 1 }),
        );
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
