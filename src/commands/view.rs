//! `prism view`: a live viewer in the browser. A local web server with one static page: the
//! page asks for frames at the camera the user moves, the server synthesises them with the
//! loaded model (`prism_train::viewer`) and answers with the images as JSON. Only its own page,
//! opened at the URL it prints, is answered ([`gate`]).

mod gate;

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use anyhow::Context;
use axum::Router;
use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, Query, State};
use axum::http::{StatusCode, header};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::{get, post};
use base64::Engine as _;
use clap::Args;
use image::{ImageEncoder as _, RgbImage};
use prism_core::BackendKind;
use prism_model::Precision;
use prism_train::viewer::{Frame, Viewer};
use serde::Deserialize;
use serde_json::json;

/// The page, served as it is (no build step, no framework).
const PAGE: &str = include_str!("view.html");

/// The largest upload accepted (a photo or a webcam frame), bytes.
const MAX_UPLOAD_BYTES: usize = 32 << 20;

/// A live viewer in the browser: move the camera around a person and watch the model answer.
///
/// Serves one page on --listen, at the URL it prints (with a token no other page knows): the
/// input is an uploaded photo (framed as `prism infer` frames
/// it), a held-out person of the dataset (with the ground truth of the recorded view the camera
/// snaps to), or the browser's camera. Drag, or use the arrow keys, to move the camera within
/// +-30 degrees. Ctrl+C stops the server.
#[derive(Args, Debug)]
pub struct ViewArgs {
    /// A checkpoint folder, or a run folder (its latest checkpoint); twice to switch between a
    /// teacher and a student.
    #[arg(long, value_name = "RUN_OR_CKPT", required = true)]
    checkpoint: Vec<PathBuf>,
    /// Address to serve the page on, and only it (loopback by default: the page shows the
    /// input's photos, and whoever has its URL can upload images to this machine).
    #[arg(long, default_value = "127.0.0.1:8080", value_name = "ADDR")]
    listen: SocketAddr,
    /// A dataset whose held-out people can be inputs [default: the first checkpoint's
    /// synthetic dataset, when it is in the cache].
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// Backend: ndarray, flex or wgpu.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// The precision of the transformer blocks: f32, f16 or bf16 (the rest of the model stays
    /// f32; bf16 on the CPU: bf16 matrix products, see the README).
    #[arg(long, default_value = "f32", value_name = "f32|f16|bf16")]
    precision: Precision,
}

impl ViewArgs {
    /// Loads the models, then serves the page until SIGINT or SIGTERM.
    pub fn run(self) -> anyhow::Result<()> {
        if self.checkpoint.len() > 2 {
            anyhow::bail!("--checkpoint takes one or two checkpoints (a teacher and a student)");
        }
        let data = match self.data {
            Some(d) => Some(d),
            None => cached_dataset(&self.checkpoint[0]),
        };
        let viewer = Viewer::open(
            &self.checkpoint,
            data.as_deref(),
            self.backend,
            self.precision,
        )
        .context("loading the viewer's models")?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .enable_all()
            .build()
            .context("starting the web server's runtime")?;
        runtime.block_on(serve(viewer, self.listen))
    }
}

/// The synthetic dataset of the checkpoint's config, when it is already in the cache.
fn cached_dataset(checkpoint: &std::path::Path) -> Option<PathBuf> {
    let config = prism_train::Checkpoint::read(checkpoint).ok()?.config;
    let dir = prism_synth::synthetic_dataset_dir(&config.data);
    dir.join(prism_data::schema::files::DATASET)
        .is_file()
        .then_some(dir)
}

/// What the handlers share.
struct App {
    /// The models and the input; they compute while holding the lock.
    viewer: Mutex<Viewer>,
    /// Frames made since the start (`/api/info`'s `frames`, beside the page's count of the
    /// frames it drew).
    frames: AtomicU64,
}

type Shared = Arc<App>;

/// Serves the page and its API on `listen` until a stop signal.
async fn serve(viewer: Viewer, listen: SocketAddr) -> anyhow::Result<()> {
    let stop = prism_remote::stop_signal().context("installing the signal handlers")?;
    let listener = tokio::net::TcpListener::bind(listen)
        .await
        .with_context(|| format!("listening on {listen}"))?;
    let (guard, token) = gate::Gate::new(listener.local_addr()?)?;
    let url = guard.page_url(&token);
    let app = App {
        viewer: Mutex::new(viewer),
        frames: AtomicU64::new(0),
    };
    let app = Router::new()
        .route("/", get(|| async { Html(PAGE) }))
        .route("/api/info", get(info))
        .route("/api/frame", get(frame))
        .route("/api/view.png", get(view_png))
        .route("/api/gaussians.ply", get(gaussians))
        .route("/api/photo", post(photo))
        .route("/api/live", post(live))
        .route("/api/person", post(person))
        .layer(DefaultBodyLimit::max(MAX_UPLOAD_BYTES))
        .layer(axum::middleware::from_fn_with_state(
            Arc::new(guard),
            gate::Gate::check,
        ))
        .with_state(Arc::new(app));
    println!("prism view: {url} (Ctrl+C stops it)");
    let _ = std::io::Write::flush(&mut std::io::stdout());
    axum::serve(
        listener,
        app.into_make_service_with_connect_info::<SocketAddr>(),
    )
    .with_graceful_shutdown(stop)
    .await
    .context("serving the viewer")?;
    eprintln!("prism view: stopped");
    Ok(())
}

/// Where the camera is and which model looks.
#[derive(Debug, Deserialize)]
struct At {
    #[serde(default)]
    model: usize,
    #[serde(default)]
    yaw: f32,
    #[serde(default)]
    pitch: f32,
}

/// Runs `work` on the viewer in a blocking thread, never on the async workers: the models
/// compute while holding the lock.
async fn with_viewer<T: Send + 'static>(
    app: Shared,
    work: impl FnOnce(&mut Viewer) -> prism_train::error::Result<T> + Send + 'static,
) -> Result<T, Response> {
    tokio::task::spawn_blocking(move || {
        let mut viewer = app.viewer.lock().unwrap_or_else(|p| p.into_inner());
        work(&mut viewer)
    })
    .await
    .map_err(|e| refusal(StatusCode::INTERNAL_SERVER_ERROR, format!("{e}")))?
    .map_err(|e| refusal(StatusCode::BAD_REQUEST, e.to_string()))
}

/// A JSON `{"error": message}` answer the page shows as it is.
fn refusal(status: StatusCode, message: String) -> Response {
    (status, axum::Json(json!({ "error": message }))).into_response()
}

/// A frame `work` makes at the camera `at`, counted in `app.frames`; refused (400) unless the
/// camera's angles are finite (a NaN passes any clamp).
async fn make_frame(
    app: Shared,
    at: At,
    work: impl FnOnce(&mut Viewer, At) -> prism_train::error::Result<Frame> + Send + 'static,
) -> Result<Frame, Response> {
    if !(at.yaw.is_finite() && at.pitch.is_finite()) {
        return Err(refusal(
            StatusCode::BAD_REQUEST,
            format!(
                "yaw and pitch are finite degrees (got yaw {}, pitch {})",
                at.yaw, at.pitch
            ),
        ));
    }
    let frame = with_viewer(app.clone(), move |v| work(v, at)).await?;
    app.frames.fetch_add(1, Ordering::Relaxed);
    Ok(frame)
}

async fn info(State(app): State<Shared>) -> Response {
    let frames = app.frames.load(Ordering::Relaxed);
    let described = with_viewer(app, move |v| {
        Ok(json!({
            "models": v.models(),
            "people": v.people(),
            "backend": v.backend().to_string(),
            "resolution": v.resolution(),
            "max_angle_deg": v.max_angle_deg(),
            "frames": frames,
        }))
    });
    match described.await {
        Ok(info) => axum::Json(info).into_response(),
        Err(refused) => refused,
    }
}

async fn frame(State(app): State<Shared>, Query(at): Query<At>) -> Response {
    match make_frame(app, at, |v, at| v.frame(at.model, at.yaw, at.pitch)).await {
        Ok(frame) => frame_json(&frame),
        Err(refused) => refused,
    }
}

async fn live(State(app): State<Shared>, Query(at): Query<At>, body: Bytes) -> Response {
    let made = make_frame(app, at, move |v, at| {
        v.set_photo(&body)?;
        v.frame(at.model, at.yaw, at.pitch)
    });
    match made.await {
        Ok(frame) => frame_json(&frame),
        Err(refused) => refused,
    }
}

async fn view_png(State(app): State<Shared>, Query(at): Query<At>) -> Response {
    match make_frame(app, at, |v, at| v.frame(at.model, at.yaw, at.pitch)).await {
        Ok(frame) => ([(header::CONTENT_TYPE, "image/png")], png_bytes(&frame.nvs)).into_response(),
        Err(refused) => refused,
    }
}

async fn gaussians(State(app): State<Shared>, Query(at): Query<At>) -> Response {
    match with_viewer(app, move |v| v.ply(at.model)).await {
        Ok(bytes) => (
            [
                (header::CONTENT_TYPE, "application/octet-stream"),
                (
                    header::CONTENT_DISPOSITION,
                    "attachment; filename=\"gaussians.ply\"",
                ),
            ],
            bytes,
        )
            .into_response(),
        Err(refused) => refused,
    }
}

async fn photo(State(app): State<Shared>, body: Bytes) -> Response {
    match with_viewer(app, move |v| v.set_photo(&body)).await {
        Ok(framing) => axum::Json(json!({ "framing": format!("{framing:?}") })).into_response(),
        Err(refused) => refused,
    }
}

/// Which held-out person to show.
#[derive(Debug, Deserialize)]
struct PersonIndex {
    index: usize,
}

async fn person(State(app): State<Shared>, Query(p): Query<PersonIndex>) -> Response {
    match with_viewer(app, move |v| v.set_person(p.index)).await {
        Ok(()) => axum::Json(json!({ "person": p.index })).into_response(),
        Err(refused) => refused,
    }
}

/// A frame as the page reads it: images as PNG data URLs, angles, PSNR and server time.
fn frame_json(frame: &Frame) -> Response {
    let url = |image: &RgbImage| {
        format!(
            "data:image/png;base64,{}",
            base64::engine::general_purpose::STANDARD.encode(png_bytes(image))
        )
    };
    axum::Json(json!({
        "nvs": url(&frame.nvs),
        "gs": frame.gs.as_ref().map(url),
        "source": url(&frame.source),
        "truth": frame.truth.as_ref().map(url),
        "psnr": frame.psnr,
        "yaw": frame.yaw_deg,
        "pitch": frame.pitch_deg,
        "server_ms": frame.seconds * 1e3,
    }))
    .into_response()
}

/// `image` encoded as PNG.
fn png_bytes(image: &RgbImage) -> Vec<u8> {
    let mut out = Vec::new();
    image::codecs::png::PngEncoder::new(&mut out)
        .write_image(
            image.as_raw(),
            image.width(),
            image.height(),
            image::ExtendedColorType::Rgb8,
        )
        .expect("encoding an RGB image into memory");
    out
}
