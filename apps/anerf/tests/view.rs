//! `anerf view`'s server, spoken to over a raw socket (so that paths reach it exactly as written): it
//! serves the page, the run's index and the run's own files, follows the log as it grows, and refuses
//! every way out of the run folder. The page itself is checked in Chromium by scripts/view/browser_test.sh.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};

use anerf_core::gaussians::Splats;
use anerf_eval::splat_ply::{write_splat_ply, SplatCloud};
use anerf_view::Viewer;

/// Status, headers (lower-cased names) and body of `request_line` sent to `addr`.
fn send(addr: &str, method: &str, target: &str) -> (u16, Vec<(String, String)>, Vec<u8>) {
    let mut stream = TcpStream::connect(addr).unwrap();
    write!(
        stream,
        "{method} {target} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut reply = Vec::new();
    stream.read_to_end(&mut reply).unwrap();
    let split = reply
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .expect("a header block");
    let head = String::from_utf8(reply[..split].to_vec()).unwrap();
    let mut lines = head.lines();
    let status = lines
        .next()
        .unwrap()
        .split(' ')
        .nth(1)
        .unwrap()
        .parse()
        .unwrap();
    let headers = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    (status, headers, reply[split + 4..].to_vec())
}

fn get(addr: &str, target: &str) -> (u16, Vec<u8>) {
    let (status, _, body) = send(addr, "GET", target);
    (status, body)
}

fn header<'a>(headers: &'a [(String, String)], name: &str) -> &'a str {
    headers
        .iter()
        .find(|(k, _)| k == name)
        .map_or("", |(_, v)| v)
}

/// The contents of a file beside the run, which no reply may carry.
const SECRET: &str = "SECRET-CONTENT";

fn log_line(stage: u32, step: u32, loss: f64) -> String {
    format!("{{\"stage\":{stage},\"step\":{step},\"loss\":{loss},\"lr\":0.001,\"psnr\":20.0}}\n")
}

/// A run folder as `anerf train`, `eval` and `export` leave it, with made-up contents, beside a secret
/// file and with a link inside that leads out.
fn fake_run(dir: &Path) -> std::path::PathBuf {
    std::fs::write(dir.join("secret.txt"), SECRET).unwrap();
    let run = dir.join("my run");
    let eval = run.join("eval/novel-view");
    std::fs::create_dir_all(eval.join("images")).unwrap();
    std::fs::create_dir_all(run.join("export")).unwrap();
    std::fs::create_dir_all(run.join("renders")).unwrap();
    std::fs::write(
        run.join("config.toml"),
        "name = \"subject 313\"\nseed = 0\n",
    )
    .unwrap();
    std::fs::write(
        run.join("metrics.jsonl"),
        log_line(1, 10, 0.05) + &log_line(1, 20, 0.03),
    )
    .unwrap();
    std::fs::write(
        eval.join("metrics.json"),
        r#"[{"split":"novel-view","frame":0,"view":1,"psnr":30.5,"ssim":0.97},
            {"split":"novel-view","frame":10,"view":3,"psnr":"inf","ssim":1.0}]"#,
    )
    .unwrap();
    std::fs::write(
        eval.join("summary.json"),
        r#"{"psnr":31.0,"ssim":0.98,"images":2}"#,
    )
    .unwrap();
    image::RgbImage::from_pixel(4, 3, image::Rgb([200, 10, 10]))
        .save(eval.join("images/novel-view_frame0000_view01_pred.png"))
        .unwrap();
    std::fs::write(run.join("export/avatar.glb"), b"glTF-bytes").unwrap();
    std::fs::write(run.join("renders/orbit_frame000000.gif"), b"GIF89a").unwrap();
    std::os::unix::fs::symlink(dir, run.join("outside")).unwrap();
    run
}

/// Serves `run` on a free port for the duration of `body`.
fn serving(run: &Path, body: impl FnOnce(&str)) {
    let viewer = Viewer::bind(run, 0).unwrap();
    let url = viewer.url();
    assert!(url.starts_with("http://127.0.0.1:"), "{url}");
    let addr = url
        .trim_start_matches("http://")
        .trim_end_matches('/')
        .to_string();
    let stop = AtomicBool::new(false);
    std::thread::scope(|s| {
        s.spawn(|| viewer.serve(&stop));
        body(&addr);
        stop.store(true, Ordering::Relaxed);
    });
}

#[test]
fn the_server_answers_the_page_the_index_and_the_runs_files() {
    let dir = tempfile::tempdir().unwrap();
    let run = fake_run(dir.path());
    serving(&run, |addr| {
        let (status, headers, page) = send(addr, "GET", "/");
        assert_eq!(status, 200);
        assert!(header(&headers, "content-type").starts_with("text/html"));
        let page = String::from_utf8(page).unwrap();
        assert!(
            page.contains(r#"<canvas id="avatar""#) && page.contains("/assets/app.js"),
            "{page}"
        );
        for asset in ["app.js", "glb_view.js", "style.css"] {
            assert_eq!(get(addr, &format!("/assets/{asset}")).0, 200, "{asset}");
        }

        let (status, body) = get(addr, "/api/run");
        assert_eq!(status, 200);
        let index: serde_json::Value = serde_json::from_slice(&body).unwrap();
        assert_eq!(index["name"], "subject 313");
        assert_eq!(index["last"]["step"], 20);
        assert!(index["log_age_s"].as_f64().unwrap() < 600.0);
        let config = std::fs::read_to_string(run.join("config.toml")).unwrap();
        assert_eq!(index["config"], config.as_str());
        let evaluation = &index["evaluations"][0];
        assert_eq!(evaluation["split"], "novel-view");
        assert_eq!(evaluation["psnr"], 31.0);
        let images = evaluation["images"].as_array().unwrap();
        assert_eq!(images.len(), 2);
        assert_eq!(
            (images[1]["frame"].as_u64(), images[1]["view"].as_u64()),
            (Some(10), Some(3))
        );
        // Only the prediction of the first record was saved; the others are absent, not broken links.
        assert!(images[0]["gt"].is_null() && images[1]["pred"].is_null());
        let pred_url = images[0]["pred"].as_str().unwrap();
        assert!(pred_url
            .starts_with("/run/eval/novel-view/images/novel-view_frame0000_view01_pred.png?v="));
        let (status, headers, png) = send(addr, "GET", pred_url);
        assert_eq!(
            (status, header(&headers, "content-type")),
            (200, "image/png")
        );
        let file =
            std::fs::read(run.join("eval/novel-view/images/novel-view_frame0000_view01_pred.png"))
                .unwrap();
        assert_eq!(png, file);

        let avatar = index["avatars"][0].as_str().unwrap();
        let (status, headers, glb) = send(addr, "GET", avatar);
        assert_eq!(
            (status, header(&headers, "content-type"), &glb[..]),
            (200, "model/gltf-binary", &b"glTF-bytes"[..])
        );
        // The baked avatar's Gaussians appear once all three files of a splat export are there.
        assert!(index["splats"].is_null(), "{index:#}");
        let splats = run.join("export/splats");
        std::fs::create_dir_all(&splats).unwrap();
        // The Gaussians must be a splat file the server can read (a corrupt one is refused, see
        // a_corrupt_splat_file_is_refused_with_the_reason); the sidecars are served as they are.
        write_splat_ply(&splats.join("avatar.ply"), &one_gaussian()).unwrap();
        std::fs::write(splats.join("skin.json"), "skin.json").unwrap();
        let partial: serde_json::Value = serde_json::from_slice(&get(addr, "/api/run").1).unwrap();
        assert!(partial["splats"].is_null(), "motion.json is missing");
        std::fs::write(splats.join("motion.json"), "motion.json").unwrap();
        let full: serde_json::Value = serde_json::from_slice(&get(addr, "/api/run").1).unwrap();
        assert_ne!(full["version"], partial["version"]);
        for (key, name) in [
            ("ply", "avatar.ply"),
            ("skin", "skin.json"),
            ("motion", "motion.json"),
        ] {
            let url = full["splats"][key].as_str().unwrap();
            assert!(
                url.starts_with(&format!("/run/export/splats/{name}?v=")),
                "{url}"
            );
            let expected = match name {
                "avatar.ply" => std::fs::read(splats.join(name)).unwrap(),
                _ => name.as_bytes().to_vec(),
            };
            assert_eq!(send(addr, "GET", url).2, expected);
        }
        assert_eq!(index["videos"][0]["kind"], "gif");
        assert_eq!(
            index["curves"].as_array().unwrap().len(),
            1,
            "stage 1 only: {index:#}"
        );

        let (status, headers, svg) = send(addr, "GET", index["curves"][0].as_str().unwrap());
        assert_eq!(
            (status, header(&headers, "content-type")),
            (200, "image/svg+xml")
        );
        assert!(String::from_utf8(svg).unwrap().contains("stage 1 loss"));
        assert_eq!(get(addr, "/live/stage2.svg").0, 404);
        assert_eq!(get(addr, "/nothing-here").0, 404);
        assert_eq!(send(addr, "POST", "/api/run").0, 405);
    });
}

#[test]
fn the_index_follows_a_run_that_is_still_training() {
    let dir = tempfile::tempdir().unwrap();
    let run = fake_run(dir.path());
    serving(&run, |addr| {
        let before: serde_json::Value = serde_json::from_slice(&get(addr, "/api/run").1).unwrap();
        let mut log = std::fs::OpenOptions::new()
            .append(true)
            .open(run.join("metrics.jsonl"))
            .unwrap();
        log.write_all(log_line(2, 5, 0.01).as_bytes()).unwrap();
        drop(log);
        let after: serde_json::Value = serde_json::from_slice(&get(addr, "/api/run").1).unwrap();
        assert_ne!(before["version"], after["version"]);
        assert_eq!(after["last"]["stage"], 2);
        let curves: Vec<&str> = after["curves"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c.as_str().unwrap())
            .collect();
        assert_eq!(curves.len(), 2);
        assert!(curves[1].starts_with("/live/stage2.svg?v="));
        // The curve's own stamp changed with the log, so the page fetches it again.
        assert_ne!(before["curves"][0], after["curves"][0]);
        // Files that did not change keep their URL (the page does not fetch them again).
        assert_eq!(before["avatars"], after["avatars"]);
        assert_eq!(get(addr, curves[1]).0, 200);
    });
}

#[test]
fn no_request_reaches_outside_the_run_folder() {
    let dir = tempfile::tempdir().unwrap();
    let run = fake_run(dir.path());
    serving(&run, |addr| {
        for target in [
            "/../secret.txt",
            "/run/../secret.txt",
            "/run/../../secret.txt",
            "/run/%2e%2e/secret.txt",
            "/run/..%2fsecret.txt",
            "/run/eval/..%2F..%2Fsecret.txt",
            "/assets/../../secret.txt",
            "/run/..\\secret.txt",
        ] {
            let (status, body) = get(addr, target);
            let body = String::from_utf8_lossy(&body);
            assert_eq!(status, 403, "{target}: {body}");
            assert!(
                body.contains("refused") && !body.contains(SECRET),
                "{target}: {body}"
            );
        }
        // A link inside the run that leads out of it.
        let (status, body) = get(addr, "/run/outside/secret.txt");
        assert_eq!(status, 403, "{}", String::from_utf8_lossy(&body));
        assert!(!String::from_utf8_lossy(&body).contains(SECRET));
        // Absolute paths are run-relative, never the file system's.
        assert_eq!(get(addr, "/run//etc/passwd").0, 404);
        assert_eq!(get(addr, "/run/").0, 404);
    });
}

/// Every file under `dir` (not following links) with its bytes.
fn files_under(dir: &Path) -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        let meta = std::fs::symlink_metadata(&path).unwrap();
        if meta.is_dir() {
            out.extend(files_under(&path));
        } else if meta.is_file() {
            out.push(std::fs::read(&path).unwrap());
        }
    }
    out
}

/// Request paths mutated from real ones (traversal tokens, encodings, separators, bytes flipped, cut and
/// repeated) are routed without a panic, answered with a status the viewer sends, and whatever is
/// served is one of the run's own files or the viewer's own output: never the secret beside the run,
/// which a link inside the run points at.
#[test]
fn mutated_request_paths_never_leave_the_run_or_panic() {
    use anerf_train::run_dir::RunDir;
    use anerf_view::routes::{route, Body};
    use rand::{Rng, SeedableRng};

    let dir = tempfile::tempdir().unwrap();
    let run = RunDir::open(&fake_run(dir.path())).unwrap();
    let run_files = files_under(&run.root);
    let seeds = [
        "/",
        "/api/run",
        "/assets/app.js",
        "/live/stage1.svg",
        "/run/config.toml",
        "/run/eval/novel-view/summary.json?v=3",
        "/run/export/avatar.glb",
        "/run/outside/secret.txt",
        "/run/eval/novel-view/images/novel-view_frame0000_view01_pred.png",
    ];
    let tokens = [
        "..",
        "../",
        "/..",
        "%2e%2e",
        "%2E.",
        ".%2e",
        "%2f",
        "%2F",
        "/",
        "//",
        "\\",
        "%5c",
        "%00",
        "%",
        "%zz",
        "%ff",
        "%c0%ae",
        "?",
        "#",
        ".",
        "~",
        "outside",
        "secret.txt",
        "/run",
        "/assets/",
        "/live/",
        "stage99999999999999999999.svg",
        "\u{202e}",
    ];
    let methods = ["GET", "GET", "GET", "HEAD", "POST", "get", ""];
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x7075);
    let mut served = 0;
    for round in 0..4000 {
        let mut url = seeds[round % seeds.len()].as_bytes().to_vec();
        for _ in 0..rng.random_range(1..4) {
            let at = rng.random_range(0..=url.len());
            match rng.random_range(0..4) {
                0 => {
                    let token = tokens[rng.random_range(0..tokens.len())].as_bytes();
                    url.splice(at..at, token.iter().copied());
                }
                1 => url.truncate(at.max(1)),
                2 if !url.is_empty() => {
                    let i = at.min(url.len() - 1);
                    url[i] ^= 1 << rng.random_range(0..7);
                }
                _ => {
                    let tail = url[at..].to_vec();
                    url.extend(tail);
                }
            }
        }
        let url = String::from_utf8_lossy(&url).into_owned();
        let method = methods[rng.random_range(0..methods.len())];
        let reply = std::panic::catch_unwind(|| route(&run, method, &url))
            .unwrap_or_else(|_| panic!("round {round}: routing {method} {url:?} panicked"));
        assert!(
            [200, 400, 403, 404, 405, 500].contains(&reply.status),
            "round {round}: {method} {url:?} answered {}",
            reply.status
        );
        let body = match reply.body {
            Body::File(mut file) => {
                let mut bytes = Vec::new();
                file.read_to_end(&mut bytes).unwrap();
                assert!(
                    run_files.contains(&bytes),
                    "round {round}: {url:?} served a file that is not the run's"
                );
                served += 1;
                bytes
            }
            Body::Owned(bytes) => bytes,
            Body::Static(bytes) => bytes.to_vec(),
        };
        assert!(
            !String::from_utf8_lossy(&body).contains(SECRET),
            "round {round}: {method} {url:?} leaked the secret"
        );
    }
    assert!(
        served > 20,
        "some mutated paths should still name run files: {served}"
    );
}

#[test]
fn view_says_what_it_expected_of_a_folder_and_of_a_port() {
    let dir = tempfile::tempdir().unwrap();
    let error = Viewer::bind(dir.path(), 0).err().unwrap().to_string();
    assert!(
        error.contains("is not a run folder") && error.contains("config.toml"),
        "{error}"
    );

    let run = fake_run(dir.path());
    let taken = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    let error = format!("{:#}", Viewer::bind(&run, port).err().unwrap());
    assert!(
        error.contains(&format!("port {port}"))
            && error.contains("taken")
            && error.contains("--port"),
        "{error}"
    );
}

#[test]
fn the_view_command_prints_its_address_and_serves_until_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let run = fake_run(dir.path());
    let mut child = Command::new(env!("CARGO_BIN_EXE_anerf"))
        .args(["view", run.to_str().unwrap(), "--port", "0"])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut line = String::new();
    BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let url = line
        .split_whitespace()
        .find(|w| w.starts_with("http://127.0.0.1:"))
        .unwrap_or_else(|| panic!("{line}"));
    let addr = url.trim_start_matches("http://").trim_end_matches('/');
    let (status, body) = get(addr, "/api/run");
    child.kill().unwrap();
    child.wait().unwrap();
    assert_eq!(status, 200, "{}", String::from_utf8_lossy(&body));

    let out = Command::new(env!("CARGO_BIN_EXE_anerf"))
        .args(["view", dir.path().join("nothing").to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("is not a run folder"), "{stderr}");
}

/// One Gaussian, for a splat file the server accepts.
fn one_gaussian() -> SplatCloud<'static> {
    SplatCloud {
        splats: Splats {
            means: &[[0.0, 1.0, 0.0]],
            log_scales: &[[-4.0; 3]],
            rotations: &[[1.0, 0.0, 0.0, 0.0]],
            opacity_logits: &[1.0],
            colours: &[0.5; 3],
        },
        sh_degree: 0,
    }
}

/// A splat file is checked before it is served: the exported layout is served as is, a truncated copy is
/// refused (422) with the file and the reason named.
#[test]
fn a_corrupt_splat_file_is_refused_with_the_reason() {
    use anerf_train::run_dir::RunDir;
    use anerf_view::routes::route;

    let dir = tempfile::tempdir().unwrap();
    let run = RunDir::open(&fake_run(dir.path())).unwrap();
    let splats = run.exports().join("splats");
    std::fs::create_dir_all(&splats).unwrap();
    let good = splats.join("avatar.ply");
    write_splat_ply(&good, &one_gaussian()).unwrap();
    let bytes = std::fs::read(&good).unwrap();
    std::fs::write(splats.join("short.ply"), &bytes[..bytes.len() - 5]).unwrap();
    assert_eq!(
        route(&run, "GET", "/run/export/splats/avatar.ply").status,
        200
    );
    let reply = route(&run, "GET", "/run/export/splats/short.ply");
    assert_eq!(reply.status, 422);
    let text = match reply.body {
        anerf_view::routes::Body::Owned(b) => String::from_utf8(b).unwrap(),
        _ => panic!("a refusal is text"),
    };
    assert!(
        text.contains("/run/export/splats/short.ply") && text.contains("truncated"),
        "{text}"
    );
}
