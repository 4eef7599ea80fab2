//! The viewer's answer to each request path: the page and its scripts (embedded in the binary), the run's
//! index as JSON, curves drawn from the current log, and the run folder's own files, nothing outside it.

use std::path::Path;

use percent_encoding::percent_decode_str;

use super::assets;
use super::index::{RunIndex, RUN_PREFIX};
use super::inside::{inside_run, Outside};
use anerf_train::plots::{read_log, stage_panels};
use anerf_train::run_dir::RunDir;

/// What one request gets back.
#[derive(Debug)]
pub struct Reply {
    pub status: u16,
    pub content_type: &'static str,
    pub body: Body,
    /// Whether the browser may keep it: the embedded assets only; run files and data change while training.
    pub cacheable: bool,
}

#[derive(Debug)]
pub enum Body {
    Static(&'static [u8]),
    Owned(Vec<u8>),
    /// A file of the run folder, checked to lie inside it.
    File(std::fs::File),
}

impl Reply {
    fn new(status: u16, content_type: &'static str, body: Body) -> Self {
        Self {
            status,
            content_type,
            body,
            cacheable: false,
        }
    }

    /// A plain-text reply, for errors.
    pub fn text(status: u16, message: String) -> Self {
        Self::new(
            status,
            "text/plain; charset=utf-8",
            Body::Owned(message.into_bytes()),
        )
    }
}

/// Answers `method url` for the run folder `run`. Only GET and HEAD are served; a path with a `..`
/// segment (raw or percent-encoded), a backslash or a NUL is refused before anything is looked up.
pub fn route(run: &RunDir, method: &str, url: &str) -> Reply {
    if method != "GET" && method != "HEAD" {
        return Reply::text(
            405,
            format!("{method} is not served; the viewer only reads"),
        );
    }
    let raw = url.split(['?', '#']).next().unwrap_or_default();
    let Ok(path) = percent_decode_str(raw).decode_utf8() else {
        return Reply::text(400, format!("{raw}: the path is not UTF-8"));
    };
    if path.split('/').any(|s| s == "..") || path.contains(['\\', '\0']) {
        return Reply::text(
            403,
            format!("refused: {raw} reaches outside the run folder"),
        );
    }
    match &*path {
        "/" | "/index.html" => asset("index.html"),
        "/api/run" => match RunIndex::read(run) {
            Ok(index) => Reply::new(
                200,
                "application/json",
                Body::Owned(serde_json::to_vec(&index).expect("the index serialises")),
            ),
            Err(e) => Reply::text(500, format!("reading the run: {e:#}")),
        },
        p if p.starts_with("/assets/") => asset(&p["/assets/".len()..]),
        p if p.starts_with("/live/") => live_curves(run, &p["/live/".len()..]),
        p if p.starts_with(RUN_PREFIX) => run_file(run, &p[RUN_PREFIX.len()..]),
        p => Reply::text(404, format!("{p}: no such page")),
    }
}

fn asset(name: &str) -> Reply {
    match assets::get(name) {
        Some(bytes) => Reply {
            cacheable: true,
            ..Reply::new(200, content_type(Path::new(name)), Body::Static(bytes))
        },
        None => Reply::text(404, format!("/assets/{name}: no such asset")),
    }
}

/// `stage<N>.svg`: stage N's figure ([`stage_panels`]) drawn from the log as it is now.
fn live_curves(run: &RunDir, name: &str) -> Reply {
    let stage = name
        .strip_prefix("stage")
        .and_then(|s| s.strip_suffix(".svg"))
        .and_then(|s| s.parse::<u64>().ok());
    let Some(stage) = stage else {
        return Reply::text(404, format!("/live/{name}: expected stage<N>.svg"));
    };
    let log = run.metrics_log();
    if let Err(why) = inside_run(run, &log) {
        let status = if why == Outside::LeadsOut { 403 } else { 404 };
        return Reply::text(status, format!("{} {why}", log.display()));
    }
    let lines = match read_log(run) {
        Ok(lines) => lines,
        Err(e) => return Reply::text(404, format!("{e:#}")),
    };
    let Some(panels) = stage_panels(&lines, stage) else {
        return Reply::text(404, format!("the log has no step of stage {stage} yet"));
    };
    match anerf_eval::plots::panels_svg(&panels) {
        Ok(svg) => Reply::new(200, "image/svg+xml", Body::Owned(svg.into_bytes())),
        Err(e) => Reply::text(500, e.to_string()),
    }
}

/// A regular file at `rel` inside the run folder ([`inside_run`]).
fn run_file(run: &RunDir, rel: &str) -> Reply {
    let shown = format!("{RUN_PREFIX}{rel}");
    // `/run//etc/x` names `etc/x` in the run: a path joined on must never replace the run folder.
    let rel = rel.trim_start_matches('/');
    let file = match inside_run(run, &run.root.join(rel)) {
        Ok(file) => file,
        Err(Outside::Missing) => {
            return Reply::text(404, format!("{shown}: no such file in the run"))
        }
        Err(Outside::NotAFile) => return Reply::text(404, format!("{shown}: not a file")),
        Err(Outside::LeadsOut) => {
            return Reply::text(
                403,
                format!("refused: {shown} leads outside the run folder"),
            )
        }
    };
    // A splat file the page would parse is read and checked whole, so that a truncated or corrupt one is
    // refused with the reason instead of failing in the browser, and the bytes sent are the bytes checked.
    if file
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ply"))
    {
        return match anerf_eval::splat_ply::load_splat_ply(
            &file,
            anerf_core::gaussians::MAX_GAUSSIANS,
        ) {
            Ok(ply) => Reply::new(200, content_type(&file), Body::Owned(ply.bytes)),
            Err(e) => Reply::text(422, format!("{shown}: {e}")),
        };
    }
    match std::fs::File::open(&file) {
        Ok(f) => Reply::new(200, content_type(&file), Body::File(f)),
        Err(e) => Reply::text(404, format!("{shown}: {e}")),
    }
}

fn content_type(path: &Path) -> &'static str {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "html" => "text/html; charset=utf-8",
        "js" => "text/javascript; charset=utf-8",
        "css" => "text/css; charset=utf-8",
        "svg" => "image/svg+xml",
        "png" => "image/png",
        "jpg" | "jpeg" => "image/jpeg",
        "gif" => "image/gif",
        "mp4" => "video/mp4",
        "glb" => "model/gltf-binary",
        "json" => "application/json",
        "toml" | "jsonl" | "csv" | "md" | "txt" => "text/plain; charset=utf-8",
        _ => "application/octet-stream",
    }
}
