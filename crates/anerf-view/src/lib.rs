//! `anerf view`: a local web page of one run (config, live training curves, evaluation images and
//! tables, videos, the exported avatar in a 3D view), served on 127.0.0.1 only. The page and its scripts
//! are embedded in the binary ([`assets`]), so it works offline; it polls the run's index and refreshes
//! while the run trains. The server only reads: nothing outside the run folder is served ([`routes`]).

pub mod assets;
pub mod http;
pub mod index;
pub mod inside;
pub mod routes;

use std::io;
use std::net::{Ipv4Addr, SocketAddr, TcpListener, TcpStream};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result};

use anerf_train::run_dir::RunDir;
use http::{read_request, write_reply};
use routes::{route, Body, Reply};

/// Requests answered at once (a video download does not hold up the page's polling).
const WORKERS: usize = 4;

/// How often a worker checks the stop flag while no request comes.
const POLL: Duration = Duration::from_millis(50);

/// A bound, not yet serving, viewer of one run.
pub struct Viewer {
    run: RunDir,
    listener: TcpListener,
    addr: SocketAddr,
}

impl Viewer {
    /// Opens the run folder `run` and binds 127.0.0.1:`port` (0: any free port). A folder that is not a
    /// run and a port that is taken are errors that say so.
    pub fn bind(run: &Path, port: u16) -> Result<Self> {
        let run = RunDir::open(run)?;
        let listener = TcpListener::bind((Ipv4Addr::LOCALHOST, port)).map_err(|e| match e.kind() {
            io::ErrorKind::AddrInUse => anyhow::anyhow!(
                "port {port} on 127.0.0.1 is taken (another `anerf view`?); give --port with a free \
                 port, or --port 0 for any"
            ),
            _ => anyhow::Error::new(e).context(format!("listening on 127.0.0.1:{port}")),
        })?;
        let addr = listener.local_addr().context("reading the bound address")?;
        // Workers poll, so that they see the stop flag.
        listener
            .set_nonblocking(true)
            .context("setting up the listening socket")?;
        Ok(Self {
            run,
            listener,
            addr,
        })
    }

    /// The page's address.
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }

    /// Answers requests until `stop` is set, each connection on one of [`WORKERS`] threads.
    pub fn serve(&self, stop: &AtomicBool) {
        std::thread::scope(|scope| {
            for _ in 0..WORKERS {
                scope.spawn(|| {
                    while !stop.load(Ordering::Relaxed) {
                        match self.listener.accept() {
                            Ok((stream, _)) => self.answer(stream),
                            Err(e) if e.kind() == io::ErrorKind::WouldBlock => {
                                std::thread::sleep(POLL)
                            }
                            Err(e) => {
                                eprintln!("warning: view: accepting a connection: {e}");
                                std::thread::sleep(POLL);
                            }
                        }
                    }
                });
            }
        });
    }

    /// Reads one request from `stream`, answers it and closes the connection.
    fn answer(&self, stream: TcpStream) {
        if let Err(e) = http::limit_time(&stream) {
            eprintln!("warning: view: setting up a connection: {e}");
            return;
        }
        let (reply, head_only) = match read_request(&stream) {
            Ok(request) => (
                route(&self.run, &request.method, &request.target),
                request.method == "HEAD",
            ),
            Err(refusal) => (Reply::text(refusal.status, refusal.message), false),
        };
        let cache = if reply.cacheable {
            "max-age=3600"
        } else {
            "no-cache"
        };
        let headers = [
            ("Content-Type", reply.content_type),
            ("Cache-Control", cache),
            ("X-Content-Type-Options", "nosniff"),
        ];
        let sent = match reply.body {
            Body::Static(bytes) => send(&stream, reply.status, &headers, head_only, bytes),
            Body::Owned(bytes) => send(&stream, reply.status, &headers, head_only, &bytes[..]),
            Body::File(mut file) => match file.metadata() {
                Ok(meta) => {
                    let body: Option<&mut dyn io::Read> = (!head_only).then_some(&mut file);
                    write_reply(&stream, reply.status, &headers, meta.len(), body)
                }
                Err(e) => Err(e),
            },
        };
        // A browser that closed the connection early (a reload) is not an error of the run.
        if let Err(e) = sent {
            let quiet = [
                io::ErrorKind::BrokenPipe,
                io::ErrorKind::ConnectionReset,
                io::ErrorKind::WouldBlock,
                io::ErrorKind::TimedOut,
            ];
            if !quiet.contains(&e.kind()) {
                eprintln!("warning: view: sending a reply: {e}");
            }
        }
    }
}

/// A reply whose body is in memory.
fn send(
    stream: &TcpStream,
    status: u16,
    headers: &[(&str, &str)],
    head_only: bool,
    mut bytes: &[u8],
) -> io::Result<()> {
    let length = bytes.len() as u64;
    let body: Option<&mut dyn io::Read> = (!head_only).then_some(&mut bytes);
    write_reply(stream, status, headers, length, body)
}
