//! `cell serve`: the grading page and the report in a browser.
//!
//! A small HTTP server (`tiny_http`, one thread) on the configured address only
//! (default `127.0.0.1`), over one trial log:
//!
//! - `GET /` lists the trials (one campaign's, or all) with their pictures, the
//!   success / partial / failure buttons and the cause; `GET /?token=T` puts the
//!   write token into the forms.
//! - `POST /grade` (form fields `trial`, `grade`, `cause`, `note`, `token`) grades a
//!   trial through [`TrialLog::grade`], as `cell grade` does: the row's grade is
//!   replaced and the history keeps every grade given.
//! - `GET /report` shows the Table-2 figures and the charts
//!   (`GET /chart/outcomes.png`, `GET /chart/causes.png`).
//! - `GET /picture/ID` sends the picture named in trial ID's row.
//! - `GET /trial/ID/history` sends the grade history as JSON.
//!
//! Every write needs the token (form field `token` or header
//! `Authorization: Bearer T`), compared in constant time; without it the answer is
//! 401 and nothing is written. A request body over [`MAX_BODY_BYTES`] gets 413, a
//! malformed one 400, an unknown trial 404, another method 405: nothing changes.

pub mod page;

use crate::fsio::FileError;
use crate::trial::log::TrialRecord;
use crate::trial::report::Report;
use crate::trial::{GradeSource, Grading, TrialError, TrialId, TrialLog, UtcTimestamp};
use page::TrialView;
use std::io::Read;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Largest request body accepted (bytes): a grade form is a few hundred.
pub const MAX_BODY_BYTES: usize = 8 * 1024;
/// Longest observer note accepted (characters).
pub const MAX_NOTE_CHARS: usize = 500;
/// Shortest token accepted from a file or the command line.
pub const MIN_TOKEN_CHARS: usize = 16;

/// Errors of the grading server.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The address could not be bound.
    #[error("cannot listen on {addr}: {detail}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        detail: String,
    },
    /// The token is too short or has characters other than printable ASCII.
    #[error("write token: {detail}")]
    BadToken {
        /// What is wrong.
        detail: String,
    },
    /// A file could not be read or written.
    #[error(transparent)]
    File(#[from] FileError),
    /// The trial log failed.
    #[error(transparent)]
    Trial(#[from] TrialError),
}

/// What the server serves and how.
#[derive(Debug, Clone)]
pub struct ServeOptions {
    /// The trial log.
    pub log_path: PathBuf,
    /// The address to listen on (port 0: any free port).
    pub bind: SocketAddr,
    /// The write token.
    pub token: String,
    /// Show this campaign only.
    pub campaign: Option<String>,
}

/// A fresh random write token: 32 hex digits from the operating system's generator.
pub fn random_token() -> String {
    use rand::RngCore;
    let mut bytes = [0u8; 16];
    rand::rngs::OsRng.fill_bytes(&mut bytes);
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Checks a token given by the operator: at least [`MIN_TOKEN_CHARS`] printable
/// ASCII characters, no spaces.
pub fn check_token(token: &str) -> Result<(), ServeError> {
    if token.chars().count() < MIN_TOKEN_CHARS {
        return Err(ServeError::BadToken {
            detail: format!(
                "{} characters, need at least {MIN_TOKEN_CHARS}",
                token.chars().count()
            ),
        });
    }
    if !token.bytes().all(|b| b.is_ascii_graphic()) {
        return Err(ServeError::BadToken {
            detail: "only printable ASCII without spaces".into(),
        });
    }
    Ok(())
}

/// Reads the token from the first line of `path`, checked.
pub fn read_token_file(path: &Path) -> Result<String, ServeError> {
    let text = crate::fsio::read_to_string(path)?;
    let token = text.lines().next().unwrap_or("").trim().to_string();
    check_token(&token)?;
    Ok(token)
}

/// Equality that takes the same time wherever the strings differ.
fn same_token(given: &str, token: &str) -> bool {
    let (a, b) = (given.as_bytes(), token.as_bytes());
    let mut diff = (a.len() ^ b.len()) as u8 | u8::from(a.len() != b.len());
    for (i, &x) in b.iter().enumerate() {
        diff |= x ^ a.get(i).copied().unwrap_or(0);
    }
    diff == 0
}

/// An HTTP answer: status, content type and body.
#[derive(Debug, Clone, PartialEq)]
pub struct Answer {
    /// Status code.
    pub status: u16,
    /// Content type.
    pub content_type: &'static str,
    /// Body.
    pub body: Vec<u8>,
    /// `Location` header of a redirect.
    pub location: Option<String>,
}

impl Answer {
    fn html(status: u16, body: String) -> Answer {
        Answer {
            status,
            content_type: "text/html; charset=utf-8",
            body: body.into_bytes(),
            location: None,
        }
    }

    fn text(status: u16, body: impl Into<String>) -> Answer {
        Answer {
            status,
            content_type: "text/plain; charset=utf-8",
            body: format!("{}\n", body.into()).into_bytes(),
            location: None,
        }
    }

    fn png(body: Vec<u8>) -> Answer {
        Answer {
            status: 200,
            content_type: "image/png",
            body,
            location: None,
        }
    }

    fn json(value: &impl serde::Serialize) -> Answer {
        Answer {
            status: 200,
            content_type: "application/json",
            body: serde_json::to_vec_pretty(value).unwrap_or_default(),
            location: None,
        }
    }

    fn redirect(to: String) -> Answer {
        Answer {
            status: 303,
            content_type: "text/plain; charset=utf-8",
            body: Vec::new(),
            location: Some(to),
        }
    }
}

/// A request as the handler sees it (independent of the HTTP library).
#[derive(Debug, Clone, PartialEq)]
pub struct Incoming<'a> {
    /// `GET`, `POST`, ...
    pub method: &'a str,
    /// Path and query.
    pub url: &'a str,
    /// `Authorization` header, if any.
    pub authorization: Option<&'a str>,
    /// `Content-Type` header, if any.
    pub content_type: Option<&'a str>,
    /// The body (at most [`MAX_BODY_BYTES`] + 1 bytes were read).
    pub body: &'a [u8],
    /// The declared body length, if any.
    pub content_length: Option<usize>,
}

/// The request handler: the log, the token and the campaign shown.
#[derive(Debug, Clone)]
pub struct Handler {
    options: ServeOptions,
}

fn query_pairs(url: &str) -> Vec<(String, String)> {
    url.split_once('?')
        .map(|(_, q)| form_urlencoded::parse(q.as_bytes()).into_owned().collect())
        .unwrap_or_default()
}

impl Handler {
    /// A handler over `options` (the token is checked).
    pub fn new(options: ServeOptions) -> Result<Handler, ServeError> {
        check_token(&options.token)?;
        Ok(Handler { options })
    }

    fn trials(&self, log: &TrialLog) -> Result<Vec<TrialRecord>, TrialError> {
        let campaign = self.options.campaign.as_deref();
        Ok(log
            .trials()?
            .into_iter()
            .filter(|t| campaign.is_none() || t.trial.campaign_id.as_deref() == campaign)
            .collect())
    }

    /// Answers one request. Never panics on any input; errors become 4xx/5xx.
    pub fn handle(&self, req: &Incoming<'_>) -> Answer {
        let path = req.url.split('?').next().unwrap_or("");
        let result = match (req.method, path) {
            ("GET", "/") => self.grading_page(req, None),
            ("GET", "/report") => self.report_page(),
            ("GET", "/chart/outcomes.png") | ("GET", "/chart/causes.png") => self.chart(path),
            ("GET", p) if p.starts_with("/picture/") => self.picture(&p["/picture/".len()..]),
            ("GET", p) if p.starts_with("/trial/") && p.ends_with("/history") => {
                self.history(&p["/trial/".len()..p.len() - "/history".len()])
            }
            ("POST", "/grade") => self.grade(req),
            (_, "/" | "/report" | "/grade") => Ok(Answer::text(405, "method not allowed")),
            (_, p)
                if p.starts_with("/picture/")
                    || p.starts_with("/trial/")
                    || p.starts_with("/chart/") =>
            {
                Ok(Answer::text(405, "method not allowed"))
            }
            _ => Ok(Answer::text(404, "not found")),
        };
        result.unwrap_or_else(|e| {
            tracing::error!("{e}");
            Answer::text(500, format!("trial log: {e}"))
        })
    }

    fn views<'a>(
        &self,
        log: &TrialLog,
        trials: &'a [TrialRecord],
        histories: &'a [Vec<crate::trial::GradeEvent>],
    ) -> Result<Vec<TrialView<'a>>, TrialError> {
        trials
            .iter()
            .zip(histories)
            .map(|(record, history)| {
                Ok(TrialView {
                    record,
                    picture_src: log
                        .picture_path(record.id)?
                        .map(|_| format!("/picture/{}", record.id)),
                    history,
                })
            })
            .collect()
    }

    fn grading_page(
        &self,
        req: &Incoming<'_>,
        message: Option<&str>,
    ) -> Result<Answer, TrialError> {
        let log = TrialLog::open_existing(&self.options.log_path)?;
        let trials = self.trials(&log)?;
        let histories = trials
            .iter()
            .map(|t| log.grade_history(t.id))
            .collect::<Result<Vec<_>, _>>()?;
        let views = self.views(&log, &trials, &histories)?;
        let pairs = query_pairs(req.url);
        let token = pairs
            .iter()
            .find(|(k, _)| k == "token")
            .map_or("", |(_, v)| v.as_str());
        let title = match &self.options.campaign {
            Some(c) => format!("Grade the trials of campaign {c}"),
            None => "Grade the trials".to_string(),
        };
        let message = message.map(str::to_string).or_else(|| {
            pairs
                .iter()
                .find(|(k, _)| k == "graded")
                .map(|(_, v)| format!("graded trial {v}"))
        });
        Ok(Answer::html(
            200,
            page::grading_page(&title, &views, token, "/grade", message.as_deref()),
        ))
    }

    fn report(&self) -> Result<(Report, Vec<TrialRecord>, TrialLog), TrialError> {
        let log = TrialLog::open_existing(&self.options.log_path)?;
        let trials = log.trials()?;
        let report = Report::from_trials(
            &trials,
            crate::trial::Scope {
                campaign_id: self.options.campaign.as_deref(),
                task: None,
            },
        );
        Ok((report, trials, log))
    }

    fn report_page(&self) -> Result<Answer, TrialError> {
        let (report, _, _) = self.report()?;
        Ok(Answer::html(
            200,
            page::report_page(&report, ["/chart/outcomes.png", "/chart/causes.png"], &[]),
        ))
    }

    fn chart(&self, path: &str) -> Result<Answer, TrialError> {
        let (report, _, _) = self.report()?;
        let canvas = if path.ends_with("outcomes.png") {
            crate::trial::plot::outcome_chart(&report).0
        } else {
            crate::trial::plot::cause_chart(&report).0
        };
        Ok(Answer::png(canvas.to_png(Path::new(path))?))
    }

    fn parse_id(text: &str) -> Option<TrialId> {
        text.parse::<TrialId>().ok().filter(|id| *id > 0)
    }

    fn picture(&self, id: &str) -> Result<Answer, TrialError> {
        let Some(id) = Self::parse_id(id) else {
            return Ok(Answer::text(404, "no such trial"));
        };
        let log = TrialLog::open_existing(&self.options.log_path)?;
        match log.picture_path(id) {
            Ok(Some(path)) => match std::fs::read(&path) {
                Ok(bytes) => Ok(Answer::png(bytes)),
                Err(e) => Ok(Answer::text(404, format!("picture of trial {id}: {e}"))),
            },
            Ok(None) => Ok(Answer::text(404, format!("trial {id} has no picture"))),
            Err(TrialError::UnknownTrial { .. }) => Ok(Answer::text(404, "no such trial")),
            Err(e) => Err(e),
        }
    }

    fn history(&self, id: &str) -> Result<Answer, TrialError> {
        let Some(id) = Self::parse_id(id) else {
            return Ok(Answer::text(404, "no such trial"));
        };
        let log = TrialLog::open_existing(&self.options.log_path)?;
        match log.trial(id) {
            Ok(_) => Ok(Answer::json(&log.grade_history(id)?)),
            Err(TrialError::UnknownTrial { .. }) => Ok(Answer::text(404, "no such trial")),
            Err(e) => Err(e),
        }
    }

    fn grade(&self, req: &Incoming<'_>) -> Result<Answer, TrialError> {
        if req.content_length.is_some_and(|n| n > MAX_BODY_BYTES) || req.body.len() > MAX_BODY_BYTES
        {
            return Ok(Answer::text(
                413,
                format!("request body over {MAX_BODY_BYTES} bytes"),
            ));
        }
        let form_type = req
            .content_type
            .map(|c| {
                c.split(';')
                    .next()
                    .unwrap_or("")
                    .trim()
                    .eq_ignore_ascii_case("application/x-www-form-urlencoded")
            })
            .unwrap_or(false);
        if !form_type {
            return Ok(Answer::text(
                415,
                "expected Content-Type application/x-www-form-urlencoded",
            ));
        }
        if std::str::from_utf8(req.body).is_err() {
            return Ok(Answer::text(400, "request body is not UTF-8"));
        }
        let pairs: Vec<(String, String)> = form_urlencoded::parse(req.body).into_owned().collect();
        let field = |name: &str| -> Result<Option<String>, Answer> {
            let mut values = pairs.iter().filter(|(k, _)| k == name);
            let first = values.next().map(|(_, v)| v.clone());
            if values.next().is_some() {
                return Err(Answer::text(400, format!("field {name} given twice")));
            }
            Ok(first)
        };
        let known = ["trial", "grade", "cause", "note", "token"];
        if let Some((k, _)) = pairs.iter().find(|(k, _)| !known.contains(&k.as_str())) {
            return Ok(Answer::text(400, format!("unknown field {k:?}")));
        }
        let fields = (|| -> Result<_, Answer> {
            Ok((
                field("trial")?,
                field("grade")?,
                field("cause")?,
                field("note")?,
                field("token")?,
            ))
        })();
        let (trial, grade, cause, note, token) = match fields {
            Ok(f) => f,
            Err(answer) => return Ok(answer),
        };
        let bearer = req
            .authorization
            .and_then(|a| a.strip_prefix("Bearer "))
            .map(str::trim);
        let given = token.as_deref().or(bearer).unwrap_or("");
        if !same_token(given, &self.options.token) {
            return Ok(Answer::text(401, "a write needs the server's token"));
        }
        let Some(id) = trial.as_deref().and_then(Self::parse_id) else {
            return Ok(Answer::text(400, "field trial: expected a trial id"));
        };
        let Some(grade) = grade else {
            return Ok(Answer::text(400, "field grade missing"));
        };
        if note
            .as_ref()
            .is_some_and(|n| n.chars().count() > MAX_NOTE_CHARS)
        {
            return Ok(Answer::text(
                400,
                format!("note over {MAX_NOTE_CHARS} characters"),
            ));
        }
        let grading = match Grading::parse(&grade, cause.as_deref(), note) {
            Ok(g) => g,
            Err(e) => return Ok(Answer::text(400, e.to_string())),
        };
        let mut log = TrialLog::open_existing(&self.options.log_path)?;
        match log.grade(id, &grading, GradeSource::Observer, UtcTimestamp::now()) {
            Ok(previous) => {
                tracing::info!(
                    trial = id,
                    %grading,
                    previous = previous.map(|p| p.to_string()).unwrap_or_default(),
                    "graded in the browser"
                );
                let mut to: String = form_urlencoded::Serializer::new(String::from("/?"))
                    .append_pair("token", &self.options.token)
                    .append_pair("graded", &id.to_string())
                    .finish();
                to.push_str(&format!("#trial-{id}"));
                Ok(Answer::redirect(to))
            }
            Err(TrialError::UnknownTrial { .. }) => Ok(Answer::text(404, format!("no trial {id}"))),
            Err(e) => Err(e),
        }
    }
}

/// The running server.
pub struct Server {
    http: tiny_http::Server,
    handler: Handler,
    addr: SocketAddr,
}

impl Server {
    /// Binds the configured address (and nothing else).
    pub fn bind(options: ServeOptions) -> Result<Server, ServeError> {
        let handler = Handler::new(options.clone())?;
        let http = tiny_http::Server::http(options.bind).map_err(|e| ServeError::Bind {
            addr: options.bind,
            detail: e.to_string(),
        })?;
        let addr = http.server_addr().to_ip().ok_or_else(|| ServeError::Bind {
            addr: options.bind,
            detail: "not an IP socket".into(),
        })?;
        Ok(Server {
            http,
            handler,
            addr,
        })
    }

    /// The address it listens on.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Serves requests one at a time until `stop()` says so (asked every 100 ms).
    pub fn run(&self, stop: impl Fn() -> bool) {
        while !stop() {
            match self.http.recv_timeout(Duration::from_millis(100)) {
                Ok(Some(request)) => self.respond(request),
                Ok(None) => {}
                Err(e) => tracing::warn!("receiving a request: {e}"),
            }
        }
    }

    fn respond(&self, mut request: tiny_http::Request) {
        let header = |name: &'static str| {
            request
                .headers()
                .iter()
                .find(|h| h.field.equiv(name))
                .map(|h| h.value.as_str().to_string())
        };
        let authorization = header("Authorization");
        let content_type = header("Content-Type");
        let content_length = request.body_length();
        let method = request.method().as_str().to_string();
        let url = request.url().to_string();
        let mut body = Vec::new();
        let too_big = content_length.is_some_and(|n| n > MAX_BODY_BYTES);
        if !too_big {
            // Read one byte past the limit to tell an oversized chunked body.
            if let Err(e) = request
                .as_reader()
                .take(MAX_BODY_BYTES as u64 + 1)
                .read_to_end(&mut body)
            {
                tracing::warn!("reading a request body: {e}");
                let _ = request.respond(tiny_http::Response::empty(400));
                return;
            }
        }
        let answer = self.handler.handle(&Incoming {
            method: &method,
            url: &url,
            authorization: authorization.as_deref(),
            content_type: content_type.as_deref(),
            body: &body,
            content_length,
        });
        tracing::debug!(%method, %url, status = answer.status, "request");
        let mut response =
            tiny_http::Response::from_data(answer.body).with_status_code(answer.status);
        if let Ok(h) =
            tiny_http::Header::from_bytes(&b"Content-Type"[..], answer.content_type.as_bytes())
        {
            response.add_header(h);
        }
        if let Some(to) = &answer.location {
            if let Ok(h) = tiny_http::Header::from_bytes(&b"Location"[..], to.as_bytes()) {
                response.add_header(h);
            }
        }
        if let Ok(h) = tiny_http::Header::from_bytes(&b"Cache-Control"[..], &b"no-store"[..]) {
            response.add_header(h);
        }
        if too_big {
            // Do not read an oversized body; close the connection after answering.
            if let Ok(h) = tiny_http::Header::from_bytes(&b"Connection"[..], &b"close"[..]) {
                response.add_header(h);
            }
        }
        if let Err(e) = request.respond(response) {
            tracing::warn!("answering {method} {url}: {e}");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_compare_whole() {
        let t = "0123456789abcdef0123";
        assert!(same_token(t, t));
        assert!(!same_token("0123456789abcdef012", t));
        assert!(!same_token("0123456789abcdef01234", t));
        assert!(!same_token("", t));
        assert!(!same_token("x123456789abcdef0123", t));
        assert_eq!(random_token().len(), 32);
        assert_ne!(random_token(), random_token());
        assert!(check_token("short").is_err());
        assert!(check_token("has a space in it, long").is_err());
    }
}
