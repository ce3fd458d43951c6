//! The `prism` command line: parses arguments and calls the library crates.

mod commands;

use clap::{Parser, Subcommand};

/// mimalloc (tensor buffers are large and short-lived: it keeps them mapped where the system
/// allocator returns them to the kernel and page-faults them in again), counting live heap
/// bytes so that `prism bench` can report the peak memory of the CPU backends.
#[global_allocator]
static ALLOCATOR: prism_model::PeakAllocator<mimalloc::MiMalloc> =
    prism_model::PeakAllocator(mimalloc::MiMalloc);

/// mimalloc's `mi_option_purge_delay`, by its place in `mi_option_e` (the same in the v2 and v3
/// sources that libmimalloc-sys builds; the crate names no constant for it). Its default in
/// the v3 that it builds is 1000 (ms), which the tests check.
const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Keeps freed memory mapped for reuse. By default mimalloc hands freed pages back to the
/// kernel after a second, and a training step (about a second on the small config) frees
/// and allocates its hundreds of MiB further apart than that, so the next step faults them in
/// again and the kernel zeroes them (11% of a teacher step's samples; BENCHMARKS, issue 43).
/// The process then keeps its peak heap mapped until it exits. `MIMALLOC_PURGE_DELAY` in the
/// environment still wins.
fn keep_freed_memory() {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: sets one of mimalloc's integer options; any value is valid for it.
        unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) };
    }
}

/// prism: real-time single-image human frontal view synthesis (PrismMirror) on Burn.
#[derive(Parser, Debug)]
#[command(name = "prism", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

/// The subcommands; each variant's arguments and `run` live in `commands/`.
#[derive(Subcommand, Debug)]
enum Command {
    /// The body model (SMPL-X layout) and the procedural humanoid.
    #[command(subcommand)]
    Body(commands::body::BodyCommand),
    /// Datasets: synthesise, render from scans, validate.
    #[command(subcommand)]
    Data(commands::data::DataCommand),
    /// Size and cost of a model config: parameters, attention kinds, tokens, FLOPs.
    Info(commands::info::InfoArgs),
    /// Benchmarks: `--config FILE --res R1,R2` times teacher, student and all-Linear forward
    /// passes and the training step; subcommands for narrower ones.
    Bench(commands::bench::BenchArgs),
    /// PSNR, SSIM and LPIPS of images (or folders of images) against ground truth.
    Metrics(commands::metrics::MetricsArgs),
    /// 3D Gaussian splatting: render standard 3DGS PLY files.
    #[command(subcommand)]
    Splat(commands::splat::SplatCommand),
    /// Convert pretrained models into prism checkpoints (`convert lvsm`).
    #[command(subcommand)]
    Convert(commands::convert::ConvertCommand),
    /// Train the full-attention teacher (AdamW, warm-up + cosine, checkpoints, validation).
    TrainTeacher(commands::train::TrainTeacherArgs),
    /// Distil the linear-attention student from a teacher (progressive schedule, ablations).
    DistillStudent(commands::distill::DistillStudentArgs),
    /// Evaluate a checkpoint on the test subjects (PSNR, SSIM, LPIPS, FPS, report), or score
    /// any method's images with --pred/--gt.
    Evaluate(commands::evaluate::EvaluateArgs),
    /// Novel views of a person from one photo (a +-30 degree sweep as PNGs and a GIF).
    Infer(commands::infer::InferArgs),
    /// Serve this machine's device to trainers on other machines (`--devices remote:...`).
    Serve(commands::serve::ServeArgs),
    /// The main job: dataset, teacher, student, evaluation of both, a table of the results.
    Quickstart(commands::quickstart::QuickstartArgs),
    /// The paper's ablation table: every row trained at one budget, scored on the same views.
    Ablate(commands::ablate::AblateArgs),
    /// A live viewer in the browser: move the camera around a person, watch the model answer.
    View(commands::view::ViewArgs),
    /// Measure on this machine's GPU what runs fastest, and keep the choice (`tune attention`).
    #[command(subcommand)]
    Tune(commands::tune::TuneCommand),
}

thread_local! {
    /// Whether a panic on this thread is the command's own, which the panic hook prints.
    static COMMAND_THREAD: std::cell::Cell<bool> = const { std::cell::Cell::new(false) };
}

impl Command {
    /// Whether the command runs on a thread of rayon's pool, the one that Burn's CPU kernels
    /// split their work on. From the main thread, each parallel op wakes a worker and puts the
    /// main thread to sleep until it is done: thousands of hand-overs a training step, and three
    /// busy threads on the cores while the workers still spin. On a worker the command shares
    /// its op with the other workers and keeps its core (the teacher's forward pass 0.88x and a
    /// training step 0.87x at 128 px on 2 cores; BENCHMARKS, issue 43).
    ///
    /// With a pool of one thread (`RAYON_NUM_THREADS=1`), its one worker runs the command and
    /// the ops inline; from the main thread, every op was a hand-over to that worker and back
    /// (0.89x to 0.96x of the time on one thread; BENCHMARKS, issue 43's "One thread").
    ///
    /// Not for the servers (`serve`, `view`), which wait on sockets, nor for training on several
    /// devices, whose device threads wait on each other: waiting there would hold one of the
    /// pool's threads (all of them with `RAYON_NUM_THREADS=1`) from the kernels.
    fn runs_on_pool(&self) -> bool {
        match self {
            Command::Serve(_) | Command::View(_) => false,
            Command::TrainTeacher(args) => args.single_device(),
            Command::DistillStudent(args) => args.single_device(),
            _ => true,
        }
    }

    /// Runs the command on this thread, whose panics the hook prints from then on.
    fn run(self) -> anyhow::Result<()> {
        COMMAND_THREAD.set(true);
        match self {
            Command::Body(cmd) => cmd.run(),
            Command::Data(cmd) => cmd.run(),
            Command::Info(args) => args.run(),
            Command::Bench(args) => args.run(),
            Command::Metrics(args) => args.run(),
            Command::Splat(cmd) => cmd.run(),
            Command::Convert(cmd) => cmd.run(),
            Command::TrainTeacher(args) => args.run(),
            Command::DistillStudent(args) => args.run(),
            Command::Evaluate(args) => args.run(),
            Command::Infer(args) => args.run(),
            Command::Quickstart(args) => args.run(),
            Command::Serve(args) => args.run(),
            Command::Ablate(args) => args.run(),
            Command::View(args) => args.run(),
            Command::Tune(cmd) => cmd.run(),
        }
    }
}

fn main() {
    COMMAND_THREAD.set(true);
    keep_freed_memory();
    // A training worker's panic (a served device that stopped answering, say) comes back to
    // the trainer, which reports it as one error naming the device, and so does a panic the
    // trainer catches on the command's thread: printing them where they happen too would bury
    // that line. Other panics of the command's thread print as usual.
    let default_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        if COMMAND_THREAD.get() && !prism_train::served::reports_panics() {
            default_hook(info);
        }
    }));
    // Attention on a GPU takes the kernels `prism tune attention` measured fastest there.
    commands::tune::record::register();
    let command = Cli::parse().command;
    let result = if command.runs_on_pool() {
        // `scope` runs its closure on a worker of the global pool (the caller waits).
        rayon::scope(|_| command.run())
    } else {
        command.run()
    };
    if let Err(err) = result {
        eprintln!("error: {err:#}");
        std::process::exit(1);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The option number is mimalloc's purge delay: it reads that option's default (1000 ms;
    /// the options beside it default to 1 and 0), and then the value set.
    #[test]
    fn the_purge_delay_option_is_the_one_set() {
        if std::env::var_os("MIMALLOC_PURGE_DELAY").is_some() {
            return; // the environment's value replaces the default, and is kept
        }
        // SAFETY: reads one of mimalloc's integer options.
        let get = || unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) };
        assert_eq!(get(), 1000);
        keep_freed_memory();
        assert_eq!(get(), -1);
    }

    /// The commands that compute run on the pool, whatever its size; the servers and
    /// several-device training on the main thread.
    #[test]
    fn the_commands_that_compute_run_on_the_pool() {
        let on_pool = |args: &[&str]| {
            let cli = Cli::try_parse_from(std::iter::once("prism").chain(args.iter().copied()));
            cli.expect("arguments parse").command.runs_on_pool()
        };
        let train = ["train-teacher", "--config", "c.toml"];
        assert!(on_pool(&train));
        assert!(on_pool(&[&train[..], &["--devices", "1"]].concat()));
        assert!(on_pool(&["evaluate", "--checkpoint", "run"]));
        assert!(on_pool(&["bench", "--config", "c.toml"]));
        assert!(!on_pool(&[&train[..], &["--devices", "2"]].concat()));
        assert!(!on_pool(
            &[
                &train[..],
                &["--devices", "local,remote:ws://127.0.0.1:7000"]
            ]
            .concat()
        ));
        let distill = ["distill-student", "--config", "c.toml", "--teacher", "t"];
        assert!(on_pool(&distill));
        assert!(!on_pool(&[&distill[..], &["--devices", "2"]].concat()));
        assert!(!on_pool(&["serve"]));
        assert!(!on_pool(&["view", "--checkpoint", "run"]));
    }
}
