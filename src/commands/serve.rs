//! `prism serve`: this machine's devices served to trainers on other machines.

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::Args;
use prism_core::BackendKind;
use prism_data::DatasetReader;
use prism_remote::{Fingerprint, ServeOptions, TransportKind, dataset_digest, read_token, serve};
use prism_train::{TrainingConfig, fingerprint};

/// Arguments of `prism serve`.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// The address to listen on, and only it; port 0 picks a free one. Loopback by default:
    /// other machines reach the server only through an address given here (e.g.
    /// `10.0.0.7:7000`). `--transport iroh` needs `0.0.0.0:PORT` or `[::]:PORT`: Burn's Iroh
    /// transport binds every interface.
    #[arg(long, value_name = "ADDR", default_value = "127.0.0.1:7000")]
    listen: SocketAddr,
    /// The file holding the token trainers must present [default: $PRISM_TOKEN].
    #[arg(long, value_name = "FILE")]
    token_file: Option<PathBuf>,
    /// websocket (unencrypted; a trusted network only) or iroh (authenticated, encrypted; any
    /// network, on every interface of this machine).
    #[arg(long, default_value = "websocket")]
    transport: TransportKind,
    /// The backend whose devices are served: ndarray, flex, wgpu or cuda.
    #[arg(long, default_value = "flex")]
    backend: BackendKind,
    /// Devices to serve: the GPUs 0..N of a GPU backend (all of a multi-GPU node); one
    /// `--devices` entry is printed per device.
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u16).range(1..))]
    devices: u16,
    /// Serve only trainers of this config's model (refused before any step otherwise).
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// A copy of the run's dataset (a folder of `prism dataset`): the server loads its device's
    /// share of every training batch from it, instead of receiving it from the trainer.
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// Iroh: the server's secret key file (created when missing), so that its node id stays
    /// the same across restarts [default: a new id at every start].
    #[arg(long, value_name = "FILE")]
    identity: Option<PathBuf>,
    /// Iroh: also reachable through n0's public relays, by node id alone.
    #[arg(long)]
    public_relays: bool,
}

impl ServeArgs {
    /// Serves until SIGINT or SIGTERM, after printing the `--devices` entry that reaches it.
    pub fn run(self) -> anyhow::Result<()> {
        // Before anything slow (a dataset's digest): a transport that cannot bind --listen alone.
        self.transport.check_listen(self.listen)?;
        let token = read_token(self.token_file.as_deref())?;
        let fingerprint = match &self.config {
            Some(path) => fingerprint(&TrainingConfig::load(path)?),
            None => Fingerprint::this_build(None),
        };
        let data = self.data.as_deref().map(DatasetReader::open).transpose()?;
        let fingerprint = match &data {
            Some(reader) => fingerprint.with_data(dataset_digest(reader)?),
            None => fingerprint,
        };
        let loads = match &self.data {
            Some(dir) => format!(", loading its shares from {}", dir.display()),
            None => String::new(),
        };
        let options = ServeOptions {
            listen: self.listen,
            transport: self.transport,
            token,
            devices: self.backend.devices(usize::from(self.devices))?,
            fingerprint,
            data,
            identity: self.identity,
            public_relays: self.public_relays,
        };
        let (backend, count) = (self.backend, self.devices);
        serve(options, &|entry| {
            // The one line to paste on the trainer's side; stdout, flushed, for scripts.
            println!("{entry}");
            let devices = if count == 1 {
                format!("the {backend} device")
            } else {
                format!("{count} {backend} devices")
            };
            eprintln!(
                "prism serve: serving {devices}{loads}; train with --devices {entry} \
                 --token-file FILE (Ctrl+C stops)"
            );
        })?;
        eprintln!("prism serve: stopped");
        Ok(())
    }
}
