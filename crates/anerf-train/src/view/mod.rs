//! `anerf view`: a local web page of one run (config, live training curves, evaluation images and
//! tables, videos, the exported avatar in a 3D view), served on 127.0.0.1 only. The page and its scripts
//! are embedded in the binary ([`assets`]), so it works offline; it polls the run's index and refreshes
//! while the run trains. The server only reads: nothing outside the run folder is served ([`routes`]).

pub mod assets;
pub mod index;
pub mod routes;

use std::io;
use std::net::{Ipv4Addr, SocketAddr, TcpListener};
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result};

use crate::run_dir::RunDir;
use routes::{route, Body};

/// Requests answered at once (a video download does not hold up the page's polling).
const WORKERS: usize = 4;

/// How often a worker checks the stop flag while no request comes.
const POLL: Duration = Duration::from_millis(200);

/// A bound, not yet serving, viewer of one run.
pub struct Viewer {
    run: RunDir,
    server: tiny_http::Server,
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
        let server = tiny_http::Server::from_listener(listener, None)
            .map_err(|e| anyhow::anyhow!("starting the server on {addr}: {e}"))?;
        Ok(Self { run, server, addr })
    }

    /// The page's address.
    pub fn url(&self) -> String {
        format!("http://{}/", self.addr)
    }

    /// Answers requests until `stop` is set.
    pub fn serve(&self, stop: &AtomicBool) {
        std::thread::scope(|scope| {
            for _ in 0..WORKERS {
                scope.spawn(|| {
                    while !stop.load(Ordering::Relaxed) {
                        match self.server.recv_timeout(POLL) {
                            Ok(Some(request)) => self.answer(request),
                            Ok(None) => {}
                            Err(e) => eprintln!("warning: view: reading a request: {e}"),
                        }
                    }
                });
            }
        });
    }

    fn answer(&self, request: tiny_http::Request) {
        let reply = route(&self.run, request.method().as_str(), request.url());
        let header = |name: &str, value: &str| {
            tiny_http::Header::from_bytes(name.as_bytes(), value.as_bytes())
                .expect("static header names and values are valid")
        };
        let cache = if reply.cacheable {
            "max-age=3600"
        } else {
            "no-cache"
        };
        let headers = [
            header("Content-Type", reply.content_type),
            header("Cache-Control", cache),
            header("X-Content-Type-Options", "nosniff"),
        ];
        let status = tiny_http::StatusCode(reply.status);
        let sent = match reply.body {
            Body::Static(bytes) => request.respond(with_headers(
                tiny_http::Response::from_data(bytes),
                status,
                headers,
            )),
            Body::Owned(bytes) => request.respond(with_headers(
                tiny_http::Response::from_data(bytes),
                status,
                headers,
            )),
            Body::File(file) => request.respond(with_headers(
                tiny_http::Response::from_file(file),
                status,
                headers,
            )),
        };
        // A browser that closed the connection early (a reload) is not an error of the run.
        if let Err(e) = sent {
            if e.kind() != io::ErrorKind::BrokenPipe && e.kind() != io::ErrorKind::ConnectionReset {
                eprintln!("warning: view: sending a reply: {e}");
            }
        }
    }
}

fn with_headers<R: io::Read>(
    response: tiny_http::Response<R>,
    status: tiny_http::StatusCode,
    headers: [tiny_http::Header; 3],
) -> tiny_http::Response<R> {
    headers
        .into_iter()
        .fold(response.with_status_code(status), |r, h| r.with_header(h))
}
