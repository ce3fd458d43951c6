//! `prism view` as a person uses it: the built binary serves a tiny teacher (ndarray, 32 px)
//! and a real headless Chromium (the distribution's package) loads the page at the URL it
//! printed, moves the camera with key presses and a drag (every frame the server makes
//! meanwhile drawn), and goes live with Chromium's fake camera. Beside the browser, the API is
//! checked directly: it listens on loopback alone (the kernel's list of its sockets), refuses
//! whoever lacks the printed token, names another host or posts from another site, refuses a
//! camera that is not finite and a request past its bound while busy, a frame equals
//! `prism infer`'s view at the same camera, bad uploads are refused with a message while the
//! server keeps serving, and SIGINT stops it cleanly.
//!
//! Chromium is found as `chromium` or `chromium-browser` on the PATH, or at `PRISM_CHROMIUM`;
//! without it the test fails saying so (`.ci/run` installs it).

use crate::browser::{self, Viewer};
use crate::common;
use crate::sockets;

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
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

/// `prism view` serving `run` on a free loopback port.
fn start_view(cache: &Path, run: &Path, data: &Path) -> Viewer {
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

/// `path` with the viewer's token added to its query.
fn with_token(viewer: &Viewer, path: &str) -> String {
    let join = if path.contains('?') { '&' } else { '?' };
    format!("{path}{join}token={}", viewer.token())
}

/// One HTTP/1.1 request of the viewer's page, with its token: the status and the body.
fn http(viewer: &Viewer, method: &str, path: &str, body: &[u8]) -> (u16, Vec<u8>) {
    let address = viewer.address();
    let head = format!("Host: {address}\r\nContent-Length: {}\r\n", body.len());
    let mut stream = send(address, method, &with_token(viewer, path), &head);
    stream.write_all(body).unwrap();
    answer(stream, Duration::from_secs(120)).unwrap()
}

/// A request to `address` whose head (`head`: header lines, each ending in CRLF) is sent, its
/// body (if any) not yet.
fn send(address: &str, method: &str, path: &str, head: &str) -> TcpStream {
    let mut stream = TcpStream::connect(address).unwrap();
    write!(
        stream,
        "{method} {path} HTTP/1.1\r\n{head}Connection: close\r\n\r\n"
    )
    .unwrap();
    stream
}

/// The answer on `stream` within `patience`: the status and the body.
fn answer(mut stream: TcpStream, patience: Duration) -> Result<(u16, Vec<u8>), String> {
    stream.set_read_timeout(Some(patience)).unwrap();
    let mut answer = Vec::new();
    stream
        .read_to_end(&mut answer)
        .map_err(|e| format!("no answer within {patience:?}: {e}"))?;
    let split = answer
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .ok_or("not an HTTP answer")?;
    let head = String::from_utf8_lossy(&answer[..split]).to_string();
    let status = head.split(' ').nth(1).unwrap().parse().unwrap();
    assert!(
        !head
            .to_ascii_lowercase()
            .contains("transfer-encoding: chunked"),
        "{head}"
    );
    Ok((status, answer[split + 4..].to_vec()))
}

/// An upload to the viewer (with its token) that announces a megabyte and sends none of it.
fn withheld_upload(viewer: &Viewer, extra: &str) -> TcpStream {
    let address = viewer.address();
    let head = format!("Host: {address}\r\n{extra}Content-Length: 1000000\r\n");
    send(address, "POST", &with_token(viewer, "/api/photo"), &head)
}

/// What each request no one but the page may make, and each request the viewer cannot serve,
/// got, where it is not the refusal expected (empty when all are refused). Asked after a photo
/// is loaded, so that a frame could be made.
fn wrong_answers(viewer: &Viewer) -> Vec<String> {
    let address = viewer.address();
    let host = format!("Host: {address}\r\n");
    let wrong_token = "0".repeat(viewer.token().len().max(32));
    let mut wrong = Vec::new();
    let mut expect = |what: &str, want: u16, got: Result<(u16, Vec<u8>), String>| match got {
        Ok((status, _)) if status == want => {}
        Ok((status, body)) => wrong.push(format!(
            "{what}: {status} {} (expected {want})",
            String::from_utf8_lossy(&body[..body.len().min(200)])
        )),
        Err(e) => wrong.push(format!("{what}: {e} (expected {want})")),
    };
    let patience = Duration::from_secs(10);
    for (what, path) in [
        ("the page without the token", "/".to_string()),
        ("the API without the token", "/api/info".into()),
        (
            "the page with a wrong token",
            format!("/?token={wrong_token}"),
        ),
        (
            "the API with a wrong token",
            format!("/api/frame?token={wrong_token}"),
        ),
    ] {
        expect(
            what,
            403,
            answer(send(address, "GET", &path, &host), patience),
        );
    }
    // DNS rebinding: another site's name pointed at this machine, the token somehow known.
    let foreign = format!("Host: rebind.example:{}\r\n", viewer.port());
    for path in ["/", "/api/frame"] {
        let got = answer(
            send(address, "GET", &with_token(viewer, path), &foreign),
            patience,
        );
        expect(&format!("{path} for another host"), 403, got);
    }
    // Another site's form or script: refused at its head, its body never read.
    let posted = withheld_upload(viewer, "Origin: http://attacker.example\r\n");
    expect("a POST from another site", 403, answer(posted, patience));
    for camera in ["yaw=NaN", "pitch=inf", "yaw=-infinity&pitch=1"] {
        let got = answer(
            send(
                address,
                "GET",
                &with_token(viewer, &format!("/api/frame?{camera}")),
                &host,
            ),
            patience,
        );
        expect(camera, 400, got);
    }
    // The bound: of five uploads whose bodies are withheld, the viewer admits four (which then
    // wait for their bodies) and tells the fifth, whichever reaches it last, that it is busy,
    // at once; so is the next request, until the four are gone.
    let mut uploads: Vec<TcpStream> = (0..5).map(|_| withheld_upload(viewer, "")).collect();
    let start = Instant::now();
    let answered = loop {
        let first = uploads.iter().position(|upload| {
            upload
                .set_read_timeout(Some(Duration::from_millis(1)))
                .unwrap();
            upload.peek(&mut [0u8; 1]).is_ok_and(|n| n > 0)
        });
        if first.is_some() || start.elapsed() > patience {
            break first;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let refused = match answered {
        Some(i) => answer(uploads.remove(i), patience),
        None => Err(format!("none of five uploads answered within {patience:?}")),
    };
    expect("the fifth upload at once", 503, refused);
    let info = || {
        answer(
            send(address, "GET", &with_token(viewer, "/api/info"), &host),
            patience,
        )
    };
    expect("a request while four wait", 503, info());
    drop(uploads);
    let start = Instant::now();
    let again = loop {
        let got = info();
        if matches!(got, Ok((200, _))) || start.elapsed() > patience {
            break got;
        }
        std::thread::sleep(Duration::from_millis(50));
    };
    expect("a request once the bound is free", 200, again);
    wrong
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
    // A precision the backend does not compute in is refused before the server starts.
    let err = common::failure(prism_with_cache(
        &cache,
        &[
            "view",
            "--checkpoint",
            s(&run),
            "--backend",
            "ndarray",
            "--precision",
            "bf16",
        ],
    ));
    assert!(
        err.contains("ndarray backend cannot compute in bf16"),
        "{err}"
    );
    let mut viewer = start_view(&cache, &run, &data);
    sockets::assert_loopback_only(viewer.child.id(), viewer.port(), "prism view");

    // The API: one model, the held-out person, the protocol's range.
    let (status, body) = http(&viewer, "GET", "/api/info", b"");
    assert_eq!(status, 200);
    let info = json(&body);
    assert_eq!(info["models"].as_array().unwrap().len(), 1);
    assert_eq!(info["people"].as_array().unwrap().len(), 1, "{info}");
    assert_eq!(info["max_angle_deg"], 30.0);

    // A bad upload gets a message, and the server keeps serving.
    let (status, body) = http(&viewer, "POST", "/api/photo", b"not an image at all");
    assert_eq!(status, 400);
    let refusal = json(&body)["error"].as_str().unwrap().to_string();
    assert!(refusal.contains("not a png or jpeg image"), "{refusal}");

    // A photo: the frame at yaw +10 is `prism infer`'s view at that camera.
    let person = info["people"][0].as_str().unwrap();
    let photo = data.join(person).join("rgb/000.png");
    let (status, _) = http(
        &viewer,
        "POST",
        "/api/photo",
        &std::fs::read(&photo).unwrap(),
    );
    assert_eq!(status, 200);
    // Who is refused, with a photo loaded.
    let wrong = wrong_answers(&viewer);
    assert!(wrong.is_empty(), "{wrong:#?}");
    let (status, png) = http(&viewer, "GET", "/api/view.png?yaw=10&pitch=0", b"");
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
    let (status, ply) = http(&viewer, "GET", "/api/gaussians.ply", b"");
    assert_eq!(status, 200);
    assert!(ply.starts_with(b"ply\n"), "a 3DGS PLY");

    // The browser: the held-out person with its ground truth, moved by the arrow keys.
    let mut browser = browser::Browser::launch(&dir.join("chromium"));
    let page = browser.open(&viewer.url);
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
    // A drag to the left turns the camera back while the mouse moves: each frame the server
    // makes meanwhile is drawn on the page, and it makes several (the view follows the mouse,
    // one frame in flight at a time, rather than jumping to where it stops).
    let idle = "!busy && sent === query()";
    browser.wait(&page, idle);
    let frames_made = || {
        json(&http(&viewer, "GET", "/api/info", b"").1)["frames"]
            .as_u64()
            .expect("/api/info counts the frames made")
    };
    let drawn_at = |b: &mut browser::Browser| -> u64 {
        let drawn = b.eval(&page, "drawn");
        drawn
            .parse()
            .unwrap_or_else(|_| panic!("the page counts the frames drawn: {drawn}"))
    };
    let (made_before, drawn_before) = (frames_made(), drawn_at(&mut browser));
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
    browser.wait(&page, idle);
    let made = frames_made() - made_before;
    browser.wait(&page, &format!("drawn === {}", drawn_before + made));
    assert!(
        made >= 2,
        "the drag made {made} frame(s), drawn {}",
        drawn_at(&mut browser) - drawn_before
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
    let pid = viewer.child.id().to_string();
    assert!(
        Command::new("kill")
            .args(["-INT", &pid])
            .status()
            .unwrap()
            .success()
    );
    let started = Instant::now();
    let status = loop {
        if let Some(status) = viewer.child.try_wait().unwrap() {
            break status;
        }
        assert!(
            started.elapsed() < Duration::from_secs(20),
            "still serving after SIGINT"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    let mut stderr = String::new();
    viewer
        .child
        .stderr
        .take()
        .unwrap()
        .read_to_string(&mut stderr)
        .unwrap();
    assert!(status.success(), "{status}: {stderr}");
    assert!(stderr.contains("prism view: stopped"), "{stderr}");
}
