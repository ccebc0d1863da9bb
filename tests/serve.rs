//! The grading page (issue 23): driven in a real headless Chromium through
//! WebDriver, the token on every write, and malformed or huge requests refused
//! without a change to the log.

use graspcell::fsio::TempDir;
use graspcell::geometry::{Pose, PoseJson};
use graspcell::mesh::procedural::{generate, Category};
use graspcell::serve::{ServeOptions, Server, MAX_BODY_BYTES};
use graspcell::trial::picture::{write_png, Part, Solid, TrialScene};
use graspcell::trial::{
    FailureCause, Grade, GradeSource, Grading, NewTrial, ObjectRef, Placement, TrialId, TrialLog,
    UtcTimestamp,
};
use nalgebra::{Point3, Vector3};
use serde_json::{json, Value};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

const TOKEN: &str = "test-token-0123456789abcdef";

fn new_trial(method: &str, placement: u32) -> NewTrial {
    NewTrial {
        started_at: UtcTimestamp::from_unix_ms(1_760_000_000_000 + i64::from(placement) * 60_000),
        category: "mug".into(),
        task: "top".into(),
        method: method.into(),
        object: ObjectRef {
            name: "mug-novel-0".into(),
            seed: Some(3),
        },
        placement: Placement {
            index: placement,
            base_from_object: PoseJson {
                xyz: [0.6, 0.0, 0.0],
                rpy: Some([0.0, 0.0, 0.4]),
                quat_xyzw: None,
            },
        },
        campaign_id: Some("web-test".into()),
        snapshot_path: None,
        fits: json!([]),
        planned_pose: None,
        planned_joints: None,
        outcome: Some(json!({"epsilon": 0.05})),
        seeds: [("trial".to_string(), u64::from(placement))].into(),
    }
}

/// A log of two trials, the first with a picture (a mug model and a "hand" box)
/// and graded failure by the simulated observer.
fn fixture_log(dir: &Path) -> (PathBuf, TrialId, TrialId) {
    let log_path = dir.join("trials.sqlite");
    let mut log = TrialLog::open(&log_path).unwrap();
    let a = log.record_trial(&new_trial("laplace", 0)).unwrap();
    let b = log.record_trial(&new_trial("best-single", 0)).unwrap();
    let failure = Grading::new(Grade::Failure, Some(FailureCause::Other), None).unwrap();
    log.grade(a, &failure, GradeSource::Simulated, UtcTimestamp::now())
        .unwrap();
    let mug = generate(Category::Mug, 3).0;
    let at = Pose::translation(0.6, 0.0, 0.0);
    let hand = parry3d_f64::shape::SharedShape::cuboid(0.03, 0.03, 0.04);
    let scene = TrialScene {
        cloud_m: mug.vertices.iter().map(|v| at * v).collect(),
        solids: vec![
            Solid::table([0.65, 0.0], [0.8, 1.2], 0.0),
            Solid::from_mesh("mug-1", Part::BestModel, &mug, &at),
            Solid::from_shape(
                "bh_palm",
                Part::Hand,
                &hand,
                &Pose::translation(0.6, 0.0, 0.2),
            )
            .unwrap(),
        ],
        contacts_m: vec![Point3::new(0.6, 0.04, 0.08)],
        base_from_camera: graspcell::geometry::look_at_optical(
            Vector3::new(1.25, 0.0, 0.8),
            Vector3::new(0.6, 0.0, 0.05),
            Vector3::z(),
        ),
        focus_m: Point3::new(0.6, 0.0, 0.06),
        caption: vec!["TEST TRIAL".into()],
    };
    let picture = dir.join("pictures").join(format!("{a}.png"));
    write_png(&scene, &picture).unwrap();
    log.set_picture(a, &picture).unwrap();
    (log_path, a, b)
}

/// The server on a free port of 127.0.0.1, in a thread, stopped on drop.
struct Running {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Running {
    fn start(log_path: &Path) -> Running {
        let server = Server::bind(ServeOptions {
            log_path: log_path.to_path_buf(),
            bind: "127.0.0.1:0".parse().unwrap(),
            token: TOKEN.to_string(),
            campaign: Some("web-test".into()),
        })
        .unwrap();
        let addr = server.local_addr();
        assert!(addr.ip().is_loopback(), "{addr}");
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let thread = std::thread::spawn(move || server.run(|| flag.load(Ordering::Relaxed)));
        Running {
            addr,
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for Running {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Sends raw bytes, returns the status code and the body (the server closes or
/// the read times out).
fn raw_http(addr: SocketAddr, request: &[u8]) -> (u16, String) {
    try_http(addr, request, Duration::from_secs(10)).unwrap_or_else(|e| panic!("{e}"))
}

/// [`raw_http`] that says what went wrong instead of panicking: a refused
/// connection, or a peer that closed or timed out before a status line.
fn try_http(addr: SocketAddr, request: &[u8], timeout: Duration) -> Result<(u16, String), String> {
    let mut stream =
        TcpStream::connect(addr).map_err(|e| format!("cannot connect to {addr}: {e}"))?;
    stream
        .set_read_timeout(Some(timeout))
        .map_err(|e| e.to_string())?;
    // A refused oversized body may be cut off: ignore write errors past the head.
    let _ = stream.write_all(request);
    let mut response = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        match stream.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => {
                response.extend_from_slice(&buf[..n]);
                let text = String::from_utf8_lossy(&response);
                if let Some((head, body)) = text.split_once("\r\n\r\n") {
                    let length = head
                        .lines()
                        .find_map(|l| {
                            l.to_ascii_lowercase()
                                .strip_prefix("content-length:")
                                .map(|v| v.trim().parse::<usize>().unwrap())
                        })
                        .unwrap_or(0);
                    if body.len() >= length {
                        break;
                    }
                }
            }
            Err(_) => break,
        }
    }
    let text = String::from_utf8_lossy(&response).into_owned();
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .ok_or_else(|| format!("no HTTP status from {addr} in {text:?}"))?;
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_string())
        .unwrap_or_default();
    Ok((status, body))
}

fn post_form(addr: SocketAddr, body: &str, extra_headers: &str) -> (u16, String) {
    let request = format!(
        "POST /grade HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/x-www-form-urlencoded\r\n\
         Content-Length: {}\r\nConnection: close\r\n{extra_headers}\r\n{body}",
        body.len()
    );
    raw_http(addr, request.as_bytes())
}

/// The log's rows and histories, for "nothing changed" checks.
fn snapshot(log_path: &Path) -> String {
    let log = TrialLog::open_existing(log_path).unwrap();
    let rows = log.trials().unwrap();
    let histories: Vec<_> = rows
        .iter()
        .map(|r| log.grade_history(r.id).unwrap())
        .collect();
    format!("{rows:?}\n{histories:?}")
}

#[test]
fn a_write_without_the_token_is_refused_and_changes_nothing() {
    let dir = TempDir::new("serve-token").unwrap();
    let (log_path, _, b) = fixture_log(&dir);
    let server = Running::start(&log_path);
    let before = snapshot(&log_path);
    for (body, headers) in [
        (format!("trial={b}&grade=success"), String::new()),
        (
            format!("trial={b}&grade=success&token=wrong-token-0123456789"),
            String::new(),
        ),
        (format!("trial={b}&grade=success&token="), String::new()),
        (
            format!("trial={b}&grade=success"),
            "Authorization: Bearer nope-nope-nope-nope\r\n".to_string(),
        ),
        // The token with one character missing.
        (
            format!(
                "trial={b}&grade=success&token={}",
                &TOKEN[..TOKEN.len() - 1]
            ),
            String::new(),
        ),
    ] {
        let (status, text) = post_form(server.addr, &body, &headers);
        assert_eq!(status, 401, "{body}: {text}");
    }
    assert_eq!(
        snapshot(&log_path),
        before,
        "a refused write changed the log"
    );
    // With the token (form field or bearer header) the same write goes through.
    let (status, _) = post_form(
        server.addr,
        &format!("trial={b}&grade=success&token={TOKEN}"),
        "",
    );
    assert_eq!(status, 303);
    let (status, _) = post_form(
        server.addr,
        &format!("trial={b}&grade=partial&cause=execution"),
        &format!("Authorization: Bearer {TOKEN}\r\n"),
    );
    assert_eq!(status, 303);
    let log = TrialLog::open_existing(&log_path).unwrap();
    let grading = log.trial(b).unwrap().grading.unwrap();
    assert_eq!(
        (grading.grade, grading.cause),
        (Grade::Partial, Some(FailureCause::Execution))
    );
    assert_eq!(log.grade_history(b).unwrap().len(), 2);
    drop(server);
}

#[test]
fn malformed_or_huge_requests_get_4xx_and_change_nothing() {
    let dir = TempDir::new("serve-malformed").unwrap();
    let (log_path, a, _) = fixture_log(&dir);
    let server = Running::start(&log_path);
    let before = snapshot(&log_path);
    let t = TOKEN;
    let cases: Vec<(String, u16)> = vec![
        (format!("trial={a}&grade=excellent&token={t}"), 400),
        (format!("trial={a}&grade=failure&token={t}"), 400), // failure without cause
        (
            format!("trial={a}&grade=success&cause=registration&token={t}"),
            400,
        ),
        (
            format!("trial={a}&grade=partial&cause=gremlins&token={t}"),
            400,
        ),
        (format!("trial=abc&grade=success&token={t}"), 400),
        (format!("trial=-3&grade=success&token={t}"), 400),
        (format!("trial=9999&grade=success&token={t}"), 404),
        (format!("grade=success&token={t}"), 400),
        (format!("trial={a}&token={t}"), 400),
        (format!("trial={a}&trial={a}&grade=success&token={t}"), 400),
        (format!("trial={a}&grade=success&admin=1&token={t}"), 400),
        (
            format!("trial={a}&grade=partial&note={}&token={t}", "x".repeat(600)),
            400,
        ),
        (format!("trial={a}&grade=success&token={t}&%ff%fe=1"), 400),
    ];
    for (body, want) in &cases {
        let (status, text) = post_form(server.addr, body, "");
        assert_eq!(status, *want, "{body}: {text}");
    }
    // Not a form; not UTF-8; a body over the limit (declared, and sent); a GET to
    // the write endpoint; a request line that is not HTTP.
    let (status, _) = raw_http(
        server.addr,
        b"POST /grade HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 2\r\nConnection: close\r\n\r\n{}",
    );
    assert_eq!(status, 415);
    let mut bad = b"POST /grade HTTP/1.1\r\nHost: x\r\nContent-Type: application/x-www-form-urlencoded\r\nContent-Length: 4\r\nConnection: close\r\n\r\n".to_vec();
    bad.extend_from_slice(&[0xff, 0xfe, b'=', b'1']);
    assert_eq!(raw_http(server.addr, &bad).0, 400);
    let huge = format!(
        "trial={a}&grade=success&token={t}&note={}",
        "y".repeat(4 * MAX_BODY_BYTES)
    );
    assert_eq!(post_form(server.addr, &huge, "").0, 413);
    let declared = format!(
        "POST /grade HTTP/1.1\r\nHost: x\r\nContent-Type: application/x-www-form-urlencoded\r\nContent-Length: 1000000000\r\nConnection: close\r\n\r\ntrial={a}"
    );
    assert_eq!(raw_http(server.addr, declared.as_bytes()).0, 413);
    let chunked = format!(
        "POST /grade HTTP/1.1\r\nHost: x\r\nContent-Type: application/x-www-form-urlencoded\r\nTransfer-Encoding: chunked\r\nConnection: close\r\n\r\n{:x}\r\n{}\r\n0\r\n\r\n",
        2 * MAX_BODY_BYTES,
        "z".repeat(2 * MAX_BODY_BYTES)
    );
    assert_eq!(raw_http(server.addr, chunked.as_bytes()).0, 413);
    assert_eq!(
        raw_http(
            server.addr,
            b"GET /grade HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
        )
        .0,
        405
    );
    let (status, _) = raw_http(server.addr, b"BLAH\r\n\r\n");
    assert!((400..500).contains(&status), "{status}");
    assert_eq!(
        raw_http(
            server.addr,
            b"GET /picture/../../etc/passwd HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
        )
        .0,
        404
    );
    assert_eq!(
        snapshot(&log_path),
        before,
        "a refused request changed the log"
    );
    drop(server);
}

/// Chromium's WebDriver, started on a free port, killed on drop.
struct Driver {
    child: Child,
    base: String,
    session: Option<String>,
    profile: PathBuf,
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// How long one WebDriver command may take: starting Chromium on a loaded 2-core
/// machine (the whole test suite runs beside it) takes many seconds.
const WEBDRIVER_TIMEOUT: Duration = Duration::from_secs(90);

/// One WebDriver command: JSON over HTTP/1.1 (the W3C WebDriver protocol).
fn webdriver(base: &str, method: &str, path: &str, body: Option<&Value>) -> Value {
    try_webdriver(base, method, path, body, WEBDRIVER_TIMEOUT).unwrap_or_else(|e| panic!("{e}"))
}

/// [`webdriver`] that returns what went wrong (transport, JSON or a WebDriver error).
fn try_webdriver(
    base: &str,
    method: &str,
    path: &str,
    body: Option<&Value>,
    timeout: Duration,
) -> Result<Value, String> {
    let addr: SocketAddr = base.trim_start_matches("http://").parse().unwrap();
    let payload = body.map(|b| b.to_string()).unwrap_or_default();
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nContent-Type: application/json\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{payload}",
        payload.len()
    );
    let (status, text) = try_http(addr, request.as_bytes(), timeout)
        .map_err(|e| format!("WebDriver {method} {path}: {e}"))?;
    let value: Value = serde_json::from_str(&text)
        .map_err(|e| format!("WebDriver {method} {path}: {status}: {e}: {text}"))?;
    if status >= 300 {
        return Err(format!("WebDriver {method} {path}: {status}: {value}"));
    }
    Ok(value["value"].clone())
}

impl Driver {
    fn start(dir: &Path) -> Driver {
        let missing: Vec<&str> = ["/usr/bin/chromium", "/usr/bin/chromedriver"]
            .into_iter()
            .filter(|p| !Path::new(p).exists())
            .collect();
        assert!(
            missing.is_empty(),
            "the browser test needs Debian's chromium and chromium-driver ({} missing); \
             `bash .ci/setup` installs them",
            missing.join(", ")
        );
        let port = free_port();
        let mut child = Command::new("/usr/bin/chromedriver")
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver starts");
        let base = format!("http://127.0.0.1:{port}");
        // Until chromedriver listens, a connection is refused, or accepted and closed
        // with no answer while it starts: both mean "not yet", until the deadline.
        let deadline = Instant::now() + Duration::from_secs(60);
        loop {
            if let Ok(Some(exit)) = child.try_wait() {
                panic!("chromedriver exited before it was ready ({exit}; port {port} taken?)");
            }
            let probe = try_webdriver(&base, "GET", "/status", None, Duration::from_secs(5));
            match probe {
                Ok(status) if status["ready"] == json!(true) => break,
                Ok(status) => assert!(
                    Instant::now() < deadline,
                    "chromedriver on port {port} not ready: {status}"
                ),
                Err(e) => assert!(
                    Instant::now() < deadline,
                    "chromedriver did not come up on port {port}: {e}"
                ),
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        let profile = dir.join("chromium-profile");
        std::fs::create_dir_all(&profile).unwrap();
        let mut driver = Driver {
            child,
            base,
            session: None,
            profile,
        };
        let caps = json!({"capabilities": {"alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": "/usr/bin/chromium",
                "args": [
                    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                    "--no-first-run", "--disable-background-networking",
                    "--disable-component-update", "--disable-sync",
                    "--disable-dev-shm-usage",
                    format!("--user-data-dir={}", driver.profile.display()),
                ]
            }
        }}});
        let session = webdriver(&driver.base, "POST", "/session", Some(&caps));
        driver.session = Some(session["sessionId"].as_str().unwrap().to_string());
        driver
    }

    fn cmd(&self, method: &str, what: &str, body: Option<Value>) -> Value {
        let path = format!("/session/{}/{what}", self.session.as_deref().unwrap());
        webdriver(&self.base, method, &path, body.as_ref())
    }

    fn find(&self, css: &str) -> String {
        let found = self.cmd(
            "POST",
            "element",
            Some(json!({"using": "css selector", "value": css})),
        );
        found
            .as_object()
            .and_then(|o| o.values().next())
            .and_then(Value::as_str)
            .unwrap_or_else(|| panic!("no element {css}: {found}"))
            .to_string()
    }

    fn script(&self, script: &str) -> Value {
        self.cmd(
            "POST",
            "execute/sync",
            Some(json!({"script": script, "args": []})),
        )
    }
}

impl Drop for Driver {
    fn drop(&mut self) {
        if let Some(s) = &self.session {
            let addr: SocketAddr = self.base.trim_start_matches("http://").parse().unwrap();
            let _ = raw_http(
                addr,
                format!(
                    "DELETE /session/{s} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n"
                )
                .as_bytes(),
            );
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

#[test]
fn grading_in_headless_chromium_writes_the_row_and_keeps_the_history() {
    let dir = TempDir::new("serve-browser").unwrap();
    let (log_path, a, _) = fixture_log(&dir);
    let server = Running::start(&log_path);
    let driver = Driver::start(&dir);
    let url = format!("http://{}/?token={TOKEN}", server.addr);
    driver.cmd("POST", "url", Some(json!({ "url": url })));

    // The trial's picture is on the page and loaded (a real PNG of the view size).
    let picture = format!("picture-{a}");
    driver.find(&format!("#{picture}"));
    let deadline = Instant::now() + Duration::from_secs(20);
    let width = loop {
        let w = driver.script(&format!(
            "const i = document.getElementById('{picture}'); return i.complete ? i.naturalWidth : 0;"
        ));
        if w.as_u64().unwrap_or(0) > 0 || Instant::now() > deadline {
            break w.as_u64().unwrap_or(0);
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    assert!(
        width >= 480,
        "the trial picture did not load: width {width}"
    );

    // Choose a cause and click "partial".
    let option = driver.find(&format!("#cause-{a} option[value='registration']"));
    driver.cmd("POST", &format!("element/{option}/click"), Some(json!({})));
    let selected = driver.script(&format!(
        "return document.getElementById('cause-{a}').value;"
    ));
    assert_eq!(selected, json!("registration"));
    let button = driver.find(&format!("#partial-{a}"));
    let text = driver.cmd("GET", &format!("element/{button}/text"), None);
    assert_eq!(text, json!("partial"));
    driver.cmd("POST", &format!("element/{button}/click"), Some(json!({})));

    // The page comes back saying so.
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        let current = driver.cmd("GET", "url", None);
        if current
            .as_str()
            .unwrap_or("")
            .contains(&format!("graded={a}"))
        {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "no redirect after grading: {current}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
    let shown = driver.script(&format!(
        "return document.querySelector('#trial-{a} [data-grade]').getAttribute('data-grade');"
    ));
    assert_eq!(shown, json!("partial"));
    drop(driver);
    drop(server);

    // The row holds the new grade; the history keeps the old one before it.
    let log = TrialLog::open_existing(&log_path).unwrap();
    let row = log.trial(a).unwrap();
    let grading = row.grading.unwrap();
    assert_eq!(grading.grade, Grade::Partial);
    assert_eq!(grading.cause, Some(FailureCause::Registration));
    assert_eq!(row.grade_source, Some(GradeSource::Observer));
    let history = log.grade_history(a).unwrap();
    assert_eq!(history.len(), 2, "{history:?}");
    assert_eq!(history[0].grading.grade, Grade::Failure);
    assert_eq!(history[0].source, GradeSource::Simulated);
    assert_eq!(history[1].grading, grading);
    assert_eq!(history[1].source, GradeSource::Observer);
}
