//! Grades kept on paper, in and out as CSV.
//!
//! Import reads a CSV with a header naming at least `trial_id` and `grade` (optional
//! `cause` and `note`; other columns are ignored, so an export can be imported back).
//! Every row is validated (errors name the file and line) and all grades are applied
//! in one transaction: either every row is imported or none is. A row with an empty
//! grade is skipped (not graded on paper), and a row equal to the trial's current
//! grade is left alone, so importing twice changes nothing.
//!
//! The dialect is RFC 4180: comma separated, fields optionally in double quotes with
//! `""` for a quote, quoted fields may span lines, CRLF or LF line ends, optional
//! UTF-8 byte-order mark, blank lines ignored.

use super::grade::{apply_grade, current_grading, GradeSource, Grading};
use super::log::{TrialId, TrialLog};
use super::time::UtcTimestamp;
use super::TrialError;
use serde::Serialize;
use std::borrow::Cow;
use std::collections::HashMap;
use std::path::Path;

/// One CSV record and the (1-based) line it starts on.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CsvRecord {
    /// Line number where the record starts.
    pub line: usize,
    /// The fields, unquoted.
    pub fields: Vec<String>,
}

/// Parses CSV text; `path` names the file in errors.
pub fn parse_csv(text: &str, path: &Path) -> Result<Vec<CsvRecord>, TrialError> {
    let err = |line: usize, detail: String| TrialError::Csv {
        path: path.to_path_buf(),
        line,
        detail,
    };
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let mut records = Vec::new();
    let mut chars = text.chars().peekable();
    let mut line = 1;
    while chars.peek().is_some() {
        let start_line = line;
        let mut fields = Vec::new();
        let mut raw_len = 0;
        loop {
            // One field.
            let mut field = String::new();
            if chars.peek() == Some(&'"') {
                chars.next();
                raw_len += 1;
                let quote_line = line;
                loop {
                    match chars.next() {
                        None => {
                            return Err(err(quote_line, "unterminated quoted field".to_string()))
                        }
                        Some('"') if chars.peek() == Some(&'"') => {
                            chars.next();
                            field.push('"');
                        }
                        Some('"') => break,
                        Some(c) => {
                            if c == '\n' {
                                line += 1;
                            }
                            field.push(c);
                        }
                    }
                }
                match chars.peek() {
                    None | Some(',') | Some('\n') | Some('\r') => {}
                    Some(c) => {
                        return Err(err(line, format!("unexpected {c:?} after a closing quote")))
                    }
                }
            } else {
                while let Some(&c) = chars.peek() {
                    if c == ',' || c == '\n' || c == '\r' {
                        break;
                    }
                    if c == '"' {
                        return Err(err(
                            line,
                            "a quote inside an unquoted field (quote the whole field)".to_string(),
                        ));
                    }
                    field.push(c);
                    raw_len += 1;
                    chars.next();
                }
            }
            fields.push(field);
            match chars.next() {
                Some(',') => {
                    raw_len += 1;
                    continue;
                }
                Some('\r') => {
                    if chars.peek() == Some(&'\n') {
                        chars.next();
                    }
                    line += 1;
                    break;
                }
                Some('\n') => {
                    line += 1;
                    break;
                }
                None => break,
                Some(c) => return Err(err(line, format!("unexpected {c:?}"))),
            }
        }
        if !(raw_len == 0 && fields.len() == 1) {
            records.push(CsvRecord {
                line: start_line,
                fields,
            });
        }
    }
    Ok(records)
}

/// One field, quoted when it has to be.
pub fn csv_field(text: &str) -> Cow<'_, str> {
    let needs_quotes = text.contains([',', '"', '\n', '\r'])
        || text.starts_with(char::is_whitespace)
        || text.ends_with(char::is_whitespace);
    if needs_quotes {
        Cow::Owned(format!("\"{}\"", text.replace('"', "\"\"")))
    } else {
        Cow::Borrowed(text)
    }
}

/// One CSV line (with `\n`) from fields.
pub fn csv_line<S: AsRef<str>>(fields: &[S]) -> String {
    let mut line = fields
        .iter()
        .map(|f| csv_field(f.as_ref()).into_owned())
        .collect::<Vec<_>>()
        .join(",");
    line.push('\n');
    line
}

/// Columns of `cell log export`, in order. The first four are what import reads.
pub const EXPORT_COLUMNS: [&str; 16] = [
    "trial_id",
    "grade",
    "cause",
    "note",
    "graded_at",
    "grade_source",
    "started_at",
    "campaign_id",
    "category",
    "task",
    "method",
    "object",
    "object_seed",
    "placement_index",
    "snapshot_path",
    "software_version",
];

/// What an import did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct ImportSummary {
    /// Data rows read.
    pub rows: usize,
    /// Trials whose grade was set or changed.
    pub graded: usize,
    /// Rows equal to the trial's current grade (left alone).
    pub unchanged: usize,
    /// Rows with an empty grade (skipped).
    pub blank: usize,
}

/// A validated import row.
struct ImportRow {
    line: usize,
    id: TrialId,
    grading: Grading,
}

/// Parses and validates a grade CSV without a trial log (what an import checks
/// before it touches the log); `path` names the file in errors.
pub fn check_grades_csv(text: &str, path: &Path) -> Result<usize, TrialError> {
    import_rows(text, path).map(|(rows, _)| rows.len())
}

/// Parses and validates every row of a grade CSV; `path` names the file in errors.
fn import_rows(text: &str, path: &Path) -> Result<(Vec<ImportRow>, ImportSummary), TrialError> {
    let err = |line: usize, detail: String| TrialError::Csv {
        path: path.to_path_buf(),
        line,
        detail,
    };
    let records = parse_csv(text, path)?;
    let Some((header, rows)) = records.split_first() else {
        return Err(err(
            1,
            "empty file (expected a header: trial_id,grade,cause,note)".into(),
        ));
    };
    let column = |name: &str| {
        header
            .fields
            .iter()
            .position(|f| f.trim().eq_ignore_ascii_case(name))
    };
    let (Some(id_col), Some(grade_col)) = (column("trial_id"), column("grade")) else {
        return Err(err(
            header.line,
            format!(
                "header {:?} lacks trial_id or grade (expected trial_id,grade,cause,note)",
                header.fields.join(",")
            ),
        ));
    };
    let (cause_col, note_col) = (column("cause"), column("note"));
    let mut summary = ImportSummary {
        rows: rows.len(),
        ..Default::default()
    };
    let mut seen: HashMap<TrialId, usize> = HashMap::new();
    let mut out = Vec::new();
    for rec in rows {
        if rec.fields.len() != header.fields.len() {
            return Err(err(
                rec.line,
                format!(
                    "{} fields, the header has {}",
                    rec.fields.len(),
                    header.fields.len()
                ),
            ));
        }
        let id_text = rec.fields[id_col].trim();
        let id: TrialId = id_text
            .parse()
            .map_err(|_| err(rec.line, format!("trial_id {id_text:?} is not an integer")))?;
        if let Some(first) = seen.insert(id, rec.line) {
            return Err(err(
                rec.line,
                format!("trial {id} is also graded on line {first}"),
            ));
        }
        let grade = rec.fields[grade_col].trim();
        if grade.is_empty() {
            summary.blank += 1;
            continue;
        }
        let cause = cause_col.map(|c| rec.fields[c].as_str());
        let note = note_col.map(|c| rec.fields[c].clone());
        let grading = Grading::parse(grade, cause, note)
            .map_err(|e| err(rec.line, format!("trial {id}: {e}")))?;
        out.push(ImportRow {
            line: rec.line,
            id,
            grading,
        });
    }
    Ok((out, summary))
}

impl TrialLog {
    /// Imports grades from the CSV file `csv_path`, all or nothing (see the module
    /// doc). `at` is recorded as the grading time.
    pub fn import_grades_csv(
        &mut self,
        csv_path: &Path,
        at: UtcTimestamp,
    ) -> Result<ImportSummary, TrialError> {
        let text = crate::fsio::read_to_string(csv_path)?;
        self.import_grades(&text, csv_path, at)
    }

    /// Imports grades from CSV text (`csv_path` names it in errors), all or nothing.
    pub fn import_grades(
        &mut self,
        text: &str,
        csv_path: &Path,
        at: UtcTimestamp,
    ) -> Result<ImportSummary, TrialError> {
        let (rows, mut summary) = import_rows(text, csv_path)?;
        let log_path = self.path.clone();
        self.write("import grades", |tx| {
            for row in &rows {
                let current = current_grading(tx, &log_path, row.id).map_err(|e| match e {
                    TrialError::UnknownTrial { id, .. } => TrialError::Csv {
                        path: csv_path.to_path_buf(),
                        line: row.line,
                        detail: format!("no trial with id {id} in {}", log_path.display()),
                    },
                    other => other,
                })?;
                if current.as_ref() == Some(&row.grading) {
                    summary.unchanged += 1;
                    continue;
                }
                apply_grade(tx, &log_path, row.id, &row.grading, GradeSource::Import, at)?;
                summary.graded += 1;
            }
            Ok(())
        })?;
        Ok(summary)
    }

    /// Every trial as CSV ([`EXPORT_COLUMNS`]), header first, in id order.
    pub fn export_csv(&self) -> Result<String, TrialError> {
        let mut out = csv_line(&EXPORT_COLUMNS);
        for t in self.trials()? {
            let g = t.grading.as_ref();
            let fields: [String; 16] = [
                t.id.to_string(),
                g.map(|g| g.grade.to_string()).unwrap_or_default(),
                g.and_then(|g| g.cause)
                    .map(|c| c.to_string())
                    .unwrap_or_default(),
                g.and_then(|g| g.note.clone()).unwrap_or_default(),
                t.graded_at.map(|a| a.to_string()).unwrap_or_default(),
                t.grade_source.map(|s| s.to_string()).unwrap_or_default(),
                t.trial.started_at.to_string(),
                t.trial.campaign_id.clone().unwrap_or_default(),
                t.trial.category.clone(),
                t.trial.task.clone(),
                t.trial.method.clone(),
                t.trial.object.name.clone(),
                t.trial
                    .object
                    .seed
                    .map(|s| s.to_string())
                    .unwrap_or_default(),
                t.trial.placement.index.to_string(),
                t.trial
                    .snapshot_path
                    .as_ref()
                    .map(|p| p.to_string_lossy().into_owned())
                    .unwrap_or_default(),
                t.software_version.clone(),
            ];
            out.push_str(&csv_line(&fields));
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> &'static Path {
        Path::new("g.csv")
    }

    fn fields(text: &str) -> Vec<(usize, Vec<String>)> {
        parse_csv(text, p())
            .unwrap()
            .into_iter()
            .map(|r| (r.line, r.fields))
            .collect()
    }

    #[test]
    fn parses_quotes_multiline_crlf_and_blank_lines() {
        let text = "\u{feff}a,b,c\r\n1,\"x, \"\"y\"\"\",\r\n\n2,\"two\nlines\",z\n3,,";
        let got = fields(text);
        let s = |v: &[&str]| v.iter().map(|x| x.to_string()).collect::<Vec<_>>();
        assert_eq!(
            got,
            vec![
                (1, s(&["a", "b", "c"])),
                (2, s(&["1", "x, \"y\"", ""])),
                (4, s(&["2", "two\nlines", "z"])),
                (6, s(&["3", "", ""])),
            ]
        );
    }

    #[test]
    fn csv_errors_name_the_line() {
        for (text, line) in [
            ("a,b\n1,\"open\n\n", 2),
            ("a,b\n1,2\n3,x\"y\n", 3),
            ("a,b\n\"q\"x,1\n", 2),
        ] {
            match parse_csv(text, p()) {
                Err(TrialError::Csv { line: l, path, .. }) => {
                    assert_eq!((l, path.as_path()), (line, p()), "{text:?}")
                }
                other => panic!("{text:?}: {other:?}"),
            }
        }
    }

    #[test]
    fn written_fields_parse_back() {
        let row = [
            "plain",
            "with,comma",
            "with \"quote\"",
            "two\nlines",
            " padded ",
            "",
        ];
        let text = csv_line(&row);
        let got = parse_csv(&text, p()).unwrap();
        assert_eq!(got[0].fields, row.map(String::from).to_vec());
    }

    #[test]
    fn import_rows_validate_each_line() {
        let cases = [
            (
                "trial_id,grade\n1,success\nx,failure\n",
                3,
                "not an integer",
            ),
            ("trial_id,grade,cause\n1,failure,\n", 2, "needs a cause"),
            ("trial_id,grade,cause\n1,great,\n", 2, "invalid grade"),
            (
                "trial_id,grade,cause\n1,failure,gremlins\n",
                2,
                "invalid failure cause",
            ),
            (
                "trial_id,grade\n1,success\n1,partial\n",
                3,
                "also graded on line 2",
            ),
            ("trial_id,grade\n1,success,extra\n", 2, "3 fields"),
            ("id,result\n1,success\n", 1, "lacks trial_id"),
            ("", 1, "empty file"),
        ];
        for (text, line, needle) in cases {
            match import_rows(text, p()) {
                Err(e @ TrialError::Csv { .. }) => {
                    let msg = e.to_string();
                    assert!(msg.starts_with(&format!("g.csv:{line}: ")), "{msg}");
                    assert!(msg.contains(needle), "{msg}");
                }
                Err(e) => panic!("{text:?}: {e}"),
                Ok(_) => panic!("{text:?}: accepted"),
            }
        }
        let (rows, summary) = import_rows(
            "Trial_ID,Grade,Cause,Note\n4,f,Registration,\"slid, fell\"\n5,,,\n",
            p(),
        )
        .unwrap();
        assert_eq!((summary.rows, summary.blank, rows.len()), (2, 1, 1));
        assert_eq!(rows[0].id, 4);
        assert_eq!(rows[0].grading.note.as_deref(), Some("slid, fell"));
    }
}
