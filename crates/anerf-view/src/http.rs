//! The viewer's HTTP/1.1, written for what it serves and nothing more: GET and HEAD, one request per
//! connection, no request bodies, a bounded request head, loopback `Host` names only, and time limits on
//! every read and write so that no client holds a worker. (A general server library allocated a request
//! body's declared length when the request was dropped, so one `Content-Length: 99999999999` aborted the
//! process.)

use std::io::{self, BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::time::Duration;

/// Largest request head (request line and headers) read, in bytes.
pub const MAX_HEAD: usize = 16 * 1024;

/// How long a client may take to send its request, and to take each part of the reply.
pub const CLIENT_TIMEOUT: Duration = Duration::from_secs(10);

/// A request the viewer answers: its method and target as sent.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Request {
    pub method: String,
    pub target: String,
}

/// Why a request is answered with an error before routing: the status and the message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal {
    pub status: u16,
    pub message: String,
}

impl Refusal {
    fn new(status: u16, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }
}

/// Reads one request head from `stream` (at most [`MAX_HEAD`] bytes) and checks it: a request line of
/// three parts, no body (`Content-Length` other than 0, or any `Transfer-Encoding`, is refused with 413
/// and never read), and a `Host` that names this machine (refused with 403 otherwise: a web page
/// elsewhere cannot reach the viewer by pointing a name of its own at 127.0.0.1).
pub fn read_request(stream: impl Read) -> Result<Request, Refusal> {
    let mut reader = BufReader::new(stream.take(MAX_HEAD as u64 + 1));
    let mut lines = Vec::new();
    let mut read = 0;
    loop {
        let mut line = Vec::new();
        let n = reader
            .read_until(b'\n', &mut line)
            .map_err(|e| Refusal::new(408, format!("reading the request: {e}")))?;
        read += n;
        if read > MAX_HEAD {
            return Err(Refusal::new(
                431,
                format!("the request head is over {MAX_HEAD} bytes"),
            ));
        }
        if n == 0 || !line.ends_with(b"\n") {
            return Err(Refusal::new(400, "the request ended before its head did"));
        }
        let text = String::from_utf8(line)
            .map_err(|_| Refusal::new(400, "the request head is not UTF-8"))?;
        let text = text.trim_end_matches(['\r', '\n']).to_string();
        if text.is_empty() {
            break;
        }
        lines.push(text);
    }
    let Some((request_line, headers)) = lines.split_first() else {
        return Err(Refusal::new(400, "an empty request"));
    };
    let parts: Vec<&str> = request_line.split(' ').collect();
    let [method, target, version] = parts[..] else {
        return Err(Refusal::new(
            400,
            format!("malformed request line {request_line:?}"),
        ));
    };
    if !version.starts_with("HTTP/1.") {
        return Err(Refusal::new(505, format!("{version} is not served")));
    }
    let mut host = None;
    for header in headers {
        let Some((name, value)) = header.split_once(':') else {
            return Err(Refusal::new(400, format!("malformed header {header:?}")));
        };
        let value = value.trim();
        match name.trim().to_ascii_lowercase().as_str() {
            "content-length" if value != "0" => {
                return Err(Refusal::new(
                    413,
                    format!("a request body of {value} bytes: the viewer takes none"),
                ))
            }
            "transfer-encoding" => {
                return Err(Refusal::new(413, "a request body: the viewer takes none"))
            }
            "host" => host = Some(value.to_string()),
            _ => {}
        }
    }
    match host {
        Some(h) if is_loopback_host(&h) => {}
        Some(h) => {
            return Err(Refusal::new(
                403,
                format!(
                    "refused: Host {h:?} is not this machine (the viewer answers requests addressed to \
                     localhost, 127.0.0.1 or [::1] only)"
                ),
            ))
        }
        None if version == "HTTP/1.0" => {}
        None => return Err(Refusal::new(400, "an HTTP/1.1 request without Host")),
    }
    Ok(Request {
        method: method.to_string(),
        target: target.to_string(),
    })
}

/// Whether a `Host` header names this machine: `localhost`, a 127.x.y.z address or `[::1]`, with or
/// without a port.
pub fn is_loopback_host(host: &str) -> bool {
    let name = if let Some(rest) = host.strip_prefix('[') {
        match rest.split_once(']') {
            Some((inside, after)) if after.is_empty() || is_port(after) => {
                return inside == "::1";
            }
            _ => return false,
        }
    } else {
        match host.rsplit_once(':') {
            Some((name, port)) if is_port(&format!(":{port}")) => name,
            Some(_) => return false,
            None => host,
        }
    };
    name.eq_ignore_ascii_case("localhost")
        || name
            .parse::<std::net::Ipv4Addr>()
            .is_ok_and(|a| a.is_loopback())
}

fn is_port(text: &str) -> bool {
    text.strip_prefix(':')
        .is_some_and(|p| !p.is_empty() && p.len() <= 5 && p.bytes().all(|b| b.is_ascii_digit()))
}

/// Writes a reply and closes the exchange: status line, `Content-Length`, `Connection: close`, the given
/// headers, then `body` unless the request was HEAD.
pub fn write_reply(
    mut stream: &TcpStream,
    status: u16,
    headers: &[(&str, &str)],
    length: u64,
    body: Option<&mut dyn Read>,
) -> io::Result<()> {
    let mut head = format!("HTTP/1.1 {status} {}\r\n", reason(status));
    head.push_str(&format!(
        "Content-Length: {length}\r\nConnection: close\r\n"
    ));
    for (name, value) in headers {
        head.push_str(&format!("{name}: {value}\r\n"));
    }
    head.push_str("\r\n");
    stream.write_all(head.as_bytes())?;
    if let Some(body) = body {
        io::copy(&mut body.take(length), &mut stream)?;
    }
    stream.flush()
}

/// Time limits on `stream`, so that a silent or slow client gives its worker back.
pub fn limit_time(stream: &TcpStream) -> io::Result<()> {
    stream.set_nonblocking(false)?;
    stream.set_read_timeout(Some(CLIENT_TIMEOUT))?;
    stream.set_write_timeout(Some(CLIENT_TIMEOUT))
}

fn reason(status: u16) -> &'static str {
    match status {
        200 => "OK",
        400 => "Bad Request",
        403 => "Forbidden",
        404 => "Not Found",
        405 => "Method Not Allowed",
        408 => "Request Timeout",
        413 => "Content Too Large",
        431 => "Request Header Fields Too Large",
        500 => "Internal Server Error",
        505 => "HTTP Version Not Supported",
        _ => "",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(head: &str) -> Result<Request, Refusal> {
        read_request(head.as_bytes())
    }

    #[test]
    fn a_plain_get_is_read() {
        let r = request("GET /api/run HTTP/1.1\r\nHost: 127.0.0.1:7007\r\nAccept: */*\r\n\r\n");
        assert_eq!(
            r,
            Ok(Request {
                method: "GET".into(),
                target: "/api/run".into()
            })
        );
    }

    #[test]
    fn bodies_foreign_hosts_and_huge_heads_are_refused_before_routing() {
        let status = |head: &str| request(head).unwrap_err().status;
        assert_eq!(
            status("GET / HTTP/1.1\r\nHost: localhost\r\nContent-Length: 99999999999\r\n\r\n"),
            413
        );
        assert_eq!(
            status("POST / HTTP/1.1\r\nHost: localhost\r\nTransfer-Encoding: chunked\r\n\r\n"),
            413
        );
        assert_eq!(
            status("GET / HTTP/1.1\r\nHost: evil.example:7007\r\n\r\n"),
            403
        );
        assert_eq!(
            status("GET / HTTP/1.1\r\nHost: 127.0.0.1.evil.example\r\n\r\n"),
            403
        );
        assert_eq!(status("GET / HTTP/1.1\r\n\r\n"), 400);
        let huge = format!(
            "GET / HTTP/1.1\r\nHost: localhost\r\nX: {}\r\n\r\n",
            "a".repeat(MAX_HEAD)
        );
        assert_eq!(status(&huge), 431);
        assert_eq!(status("GET / HTTP/1.1\r\nHost: localhost\r\n"), 400);
        assert_eq!(status("GET /\r\n\r\n"), 400);
    }

    /// Mutated requests (bytes flipped, cut, repeated, huge numbers spliced in) are answered or refused,
    /// never a panic, and the refusal is one of the statuses the server sends; routing the targets that
    /// pass never leaves the run (checked in tests/view.rs for the forms that matter).
    #[test]
    fn mutated_requests_are_refused_or_read_never_a_panic() {
        use rand::{Rng, SeedableRng};
        let seeds = [
            "GET /api/run HTTP/1.1\r\nHost: 127.0.0.1:7007\r\n\r\n",
            "HEAD /run/eval/novel-view/metrics.json?v=1 HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n",
            "GET /live/stage1.svg HTTP/1.0\r\nContent-Length: 0\r\n\r\n",
        ];
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x4177);
        let mut refused = 0;
        for round in 0..3000 {
            let mut bytes = seeds[round % seeds.len()].as_bytes().to_vec();
            for _ in 0..rng.random_range(1..4) {
                let at = rng.random_range(0..bytes.len().max(1));
                match rng.random_range(0..4) {
                    0 if !bytes.is_empty() => {
                        let i = at.min(bytes.len() - 1);
                        bytes[i] ^= 1 << rng.random_range(0..8);
                    }
                    1 => bytes.truncate(at),
                    2 => {
                        let junk = [
                            "99999999999999999999",
                            "\r\n",
                            ":",
                            "\0",
                            "Content-Length: 5\r\n",
                            "Host: evil\r\n",
                        ];
                        let j = junk[rng.random_range(0..junk.len())].as_bytes();
                        bytes.splice(at.min(bytes.len())..at.min(bytes.len()), j.iter().copied());
                    }
                    _ => {
                        let chunk = bytes[at.min(bytes.len())..].to_vec();
                        bytes.extend(chunk);
                    }
                }
            }
            match std::panic::catch_unwind(|| read_request(&bytes[..])) {
                Ok(Ok(_)) => {}
                Ok(Err(r)) => {
                    refused += 1;
                    assert!(
                        [400, 403, 408, 413, 431, 505].contains(&r.status),
                        "round {round}: status {} for {:?}",
                        r.status,
                        String::from_utf8_lossy(&bytes)
                    );
                }
                Err(_) => panic!(
                    "round {round}: panicked on {:?}",
                    String::from_utf8_lossy(&bytes)
                ),
            }
        }
        assert!(
            refused > 300,
            "mutations should often break requests: {refused} refused"
        );
    }

    #[test]
    fn loopback_hosts_are_recognised() {
        for ok in [
            "localhost",
            "LOCALHOST:80",
            "127.0.0.1",
            "127.0.0.1:7007",
            "127.1.2.3:1",
            "[::1]",
            "[::1]:7007",
        ] {
            assert!(is_loopback_host(ok), "{ok}");
        }
        for bad in [
            "evil.example",
            "10.0.0.1",
            "127.0.0.1:",
            "127.0.0.1:x",
            "[::2]",
            "[::1]x",
            "localhost.evil",
            "",
        ] {
            assert!(!is_loopback_host(bad), "{bad}");
        }
    }
}
