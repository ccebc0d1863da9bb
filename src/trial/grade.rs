//! Grades, failure causes, grading a trial (with history) and the observer's prompt.
//!
//! A grade is success (+1), partial (0) or failure (-1), as in the paper. A failure
//! must name its cause; a partial grasp may; a success may not. Re-grading a trial
//! replaces its current grade and appends to `grade_history`, so no grade is lost.

use super::log::{TrialId, TrialLog};
use super::time::UtcTimestamp;
use super::TrialError;
use rusqlite::{params, Transaction};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::io::{BufRead, Write};
use std::path::Path;
use std::str::FromStr;

/// The observer's grade of one grasp.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Grade {
    /// The object was grasped and held as the task needs.
    Success,
    /// The object was grasped, but not (only) as intended.
    Partial,
    /// The object was not grasped.
    Failure,
}

impl Grade {
    /// Every grade, best first.
    pub const ALL: [Grade; 3] = [Grade::Success, Grade::Partial, Grade::Failure];

    /// The sign-test encoding: success +1, partial 0, failure -1.
    pub fn score(self) -> i8 {
        match self {
            Grade::Success => 1,
            Grade::Partial => 0,
            Grade::Failure => -1,
        }
    }

    /// The stored name: `success`, `partial` or `failure`.
    pub fn as_str(self) -> &'static str {
        match self {
            Grade::Success => "success",
            Grade::Partial => "partial",
            Grade::Failure => "failure",
        }
    }
}

impl fmt::Display for Grade {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Grade {
    type Err = TrialError;

    /// Accepts the names and their first letters, in any case (`success`, `S`, ...).
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text.trim().to_ascii_lowercase().as_str() {
            "success" | "s" => Ok(Grade::Success),
            "partial" | "p" => Ok(Grade::Partial),
            "failure" | "f" => Ok(Grade::Failure),
            _ => Err(TrialError::InvalidGrade {
                text: text.to_string(),
            }),
        }
    }
}

/// Why a grasp failed (or was only partial), as attributed by the observer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FailureCause {
    /// The planned grasp could not be reached by the arm.
    Reachability,
    /// The object's pose was estimated wrongly (registration failed).
    Registration,
    /// The object's shape differed from the models' where the grasp was planned.
    ShapeDissimilarity,
    /// The execution went wrong (collision, slip, hardware).
    Execution,
    /// Anything else.
    Other,
}

impl FailureCause {
    /// Every cause, in the paper's Table 2 order (plus execution).
    pub const ALL: [FailureCause; 5] = [
        FailureCause::Reachability,
        FailureCause::Registration,
        FailureCause::ShapeDissimilarity,
        FailureCause::Execution,
        FailureCause::Other,
    ];

    /// The stored name: `reachability`, `registration`, `shape-dissimilarity`,
    /// `execution` or `other`.
    pub fn as_str(self) -> &'static str {
        match self {
            FailureCause::Reachability => "reachability",
            FailureCause::Registration => "registration",
            FailureCause::ShapeDissimilarity => "shape-dissimilarity",
            FailureCause::Execution => "execution",
            FailureCause::Other => "other",
        }
    }
}

impl fmt::Display for FailureCause {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for FailureCause {
    type Err = TrialError;

    /// Accepts the names in any case, with `-`, `_` or a space in
    /// `shape-dissimilarity`, and `registration failure` for `registration`.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let norm: String = text
            .trim()
            .to_ascii_lowercase()
            .chars()
            .map(|c| if c == '_' || c == ' ' { '-' } else { c })
            .collect();
        match norm.as_str() {
            "reachability" => Ok(FailureCause::Reachability),
            "registration" | "registration-failure" => Ok(FailureCause::Registration),
            "shape-dissimilarity" => Ok(FailureCause::ShapeDissimilarity),
            "execution" => Ok(FailureCause::Execution),
            "other" => Ok(FailureCause::Other),
            _ => Err(TrialError::InvalidCause {
                text: text.to_string(),
            }),
        }
    }
}

/// Who or what gave a grade.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GradeSource {
    /// The observer at the terminal prompt, right after the grasp.
    Observer,
    /// `cell grade` on the command line.
    Command,
    /// `cell log import` from grades kept on paper.
    Import,
    /// The simulated observer of the simulated cell.
    Simulated,
}

impl GradeSource {
    /// The stored name.
    pub fn as_str(self) -> &'static str {
        match self {
            GradeSource::Observer => "observer",
            GradeSource::Command => "command",
            GradeSource::Import => "import",
            GradeSource::Simulated => "simulated",
        }
    }
}

impl fmt::Display for GradeSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for GradeSource {
    type Err = TrialError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text {
            "observer" => Ok(GradeSource::Observer),
            "command" => Ok(GradeSource::Command),
            "import" => Ok(GradeSource::Import),
            "simulated" => Ok(GradeSource::Simulated),
            _ => Err(TrialError::InvalidGradeSource {
                text: text.to_string(),
            }),
        }
    }
}

/// A validated grade: the grade, the cause (required for a failure, allowed for a
/// partial grasp, forbidden for a success) and the observer's note.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Grading {
    /// The grade.
    pub grade: Grade,
    /// The failure cause.
    pub cause: Option<FailureCause>,
    /// The observer's note (`None` when empty).
    pub note: Option<String>,
}

impl Grading {
    /// A grading, checked: a failure needs a cause, a success has none. An empty or
    /// blank note becomes `None`.
    pub fn new(
        grade: Grade,
        cause: Option<FailureCause>,
        note: Option<String>,
    ) -> Result<Self, TrialError> {
        match (grade, cause) {
            (Grade::Failure, None) => return Err(TrialError::CauseRequired),
            (Grade::Success, Some(cause)) => return Err(TrialError::CauseOnSuccess { cause }),
            _ => {}
        }
        let note = note.map(|n| n.trim().to_string()).filter(|n| !n.is_empty());
        Ok(Grading { grade, cause, note })
    }

    /// Parses a grade and an optional cause from text (empty cause text = none).
    pub fn parse(
        grade: &str,
        cause: Option<&str>,
        note: Option<String>,
    ) -> Result<Self, TrialError> {
        let grade: Grade = grade.parse()?;
        let cause = cause
            .map(str::trim)
            .filter(|c| !c.is_empty())
            .map(str::parse)
            .transpose()?;
        Grading::new(grade, cause, note)
    }
}

impl fmt::Display for Grading {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.grade)?;
        if let Some(cause) = self.cause {
            write!(f, " ({cause})")?;
        }
        if let Some(note) = &self.note {
            write!(f, ": {note}")?;
        }
        Ok(())
    }
}

/// One entry of a trial's grade history.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct GradeEvent {
    /// The trial.
    pub trial_id: TrialId,
    /// The grade given.
    #[serde(flatten)]
    pub grading: Grading,
    /// When it was given.
    pub graded_at: UtcTimestamp,
    /// Who gave it.
    pub source: GradeSource,
}

/// Sets the current grade of trial `id` and appends it to the history, inside `tx`.
/// Returns the grade it replaced.
pub(super) fn apply_grade(
    tx: &Transaction<'_>,
    path: &Path,
    id: TrialId,
    grading: &Grading,
    source: GradeSource,
    at: UtcTimestamp,
) -> Result<Option<Grading>, TrialError> {
    let sql = |op: &'static str| {
        let path = path.to_path_buf();
        move |source| TrialError::Sqlite { path, op, source }
    };
    let previous = current_grading(tx, path, id)?;
    let at_text = at.to_string();
    let cause = grading.cause.map(FailureCause::as_str);
    tx.execute(
        "INSERT INTO grade_history (trial_id, grade, failure_cause, observer_note, graded_at, source)
         VALUES (?1, ?2, ?3, ?4, ?5, ?6)",
        params![id, grading.grade.as_str(), cause, grading.note, at_text, source.as_str()],
    )
    .map_err(sql("append grade history"))?;
    tx.execute(
        "UPDATE trials SET grade = ?2, failure_cause = ?3, observer_note = ?4, graded_at = ?5,
             grade_source = ?6
         WHERE id = ?1",
        params![
            id,
            grading.grade.as_str(),
            cause,
            grading.note,
            at_text,
            source.as_str()
        ],
    )
    .map_err(sql("set grade"))?;
    Ok(previous)
}

/// The current grade of trial `id` (an error if there is no such trial), inside `tx`.
pub(super) fn current_grading(
    tx: &rusqlite::Transaction<'_>,
    path: &Path,
    id: TrialId,
) -> Result<Option<Grading>, TrialError> {
    let sql = |source| TrialError::Sqlite {
        path: path.to_path_buf(),
        op: "read grade",
        source,
    };
    let mut stmt = tx
        .prepare_cached("SELECT grade, failure_cause, observer_note FROM trials WHERE id = ?1")
        .map_err(sql)?;
    let mut rows = stmt.query([id]).map_err(sql)?;
    let Some(row) = rows.next().map_err(sql)? else {
        return Err(TrialError::UnknownTrial {
            path: path.to_path_buf(),
            id,
        });
    };
    let grade: Option<String> = row.get(0).map_err(sql)?;
    let cause: Option<String> = row.get(1).map_err(sql)?;
    let note: Option<String> = row.get(2).map_err(sql)?;
    grade
        .map(|g| Grading::parse(&g, cause.as_deref(), note))
        .transpose()
}

/// A `grade_history` row as stored: grade, cause, note, graded_at, source.
type HistoryRow = (String, Option<String>, Option<String>, String, String);

impl TrialLog {
    /// Grades trial `id` in one transaction: sets its current grade and appends to its
    /// history. Returns the grade it replaced, if any. An unknown id is an error and
    /// changes nothing.
    pub fn grade(
        &mut self,
        id: TrialId,
        grading: &Grading,
        source: GradeSource,
        at: UtcTimestamp,
    ) -> Result<Option<Grading>, TrialError> {
        let path = self.path.clone();
        self.write("grade trial", |tx| {
            apply_grade(tx, &path, id, grading, source, at)
        })
    }

    /// Every grade trial `id` has been given, oldest first.
    pub fn grade_history(&self, id: TrialId) -> Result<Vec<GradeEvent>, TrialError> {
        let sql = |source| TrialError::Sqlite {
            path: self.path.clone(),
            op: "read grade history",
            source,
        };
        let mut stmt = self
            .conn
            .prepare(
                "SELECT grade, failure_cause, observer_note, graded_at, source
                 FROM grade_history WHERE trial_id = ?1 ORDER BY id",
            )
            .map_err(sql)?;
        let rows: Vec<HistoryRow> = stmt
            .query_map([id], |r| {
                Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?, r.get(4)?))
            })
            .and_then(|rows| rows.collect())
            .map_err(sql)?;
        rows.into_iter()
            .map(|(grade, cause, note, at, source)| {
                let bad = |field, e: TrialError| TrialError::BadRow {
                    path: self.path.clone(),
                    id,
                    field,
                    detail: e.to_string(),
                };
                Ok(GradeEvent {
                    trial_id: id,
                    grading: Grading::parse(&grade, cause.as_deref(), note)
                        .map_err(|e| bad("grade_history.grade", e))?,
                    graded_at: at.parse().map_err(|e| bad("grade_history.graded_at", e))?,
                    source: source.parse().map_err(|e| bad("grade_history.source", e))?,
                })
            })
            .collect()
    }
}

/// Reads one line; `None` at end of input.
fn read_answer<R: BufRead>(input: &mut R) -> Result<Option<String>, TrialError> {
    let mut line = String::new();
    let n = input.read_line(&mut line).map_err(TrialError::PromptIo)?;
    Ok((n > 0).then(|| line.trim().to_string()))
}

fn ask<R: BufRead, W: Write>(
    input: &mut R,
    output: &mut W,
    question: &str,
) -> Result<String, TrialError> {
    write!(output, "{question}").map_err(TrialError::PromptIo)?;
    output.flush().map_err(TrialError::PromptIo)?;
    read_answer(input)?.ok_or(TrialError::PromptAborted)
}

fn say<W: Write>(output: &mut W, text: &str) -> Result<(), TrialError> {
    writeln!(output, "{text}").map_err(TrialError::PromptIo)
}

/// Asks the observer for a grade at the terminal: `s` / `p` / `f`, then the cause
/// (a number or a name; required for a failure, optional for a partial grasp), then a
/// note. Invalid answers are explained and asked again; end of input before the
/// grade is complete is [`TrialError::PromptAborted`].
pub fn prompt_grade<R: BufRead, W: Write>(
    mut input: R,
    mut output: W,
) -> Result<Grading, TrialError> {
    let grade = loop {
        let answer = ask(
            &mut input,
            &mut output,
            "Grade: [s]uccess, [p]artial, [f]ailure? ",
        )?;
        match answer.parse::<Grade>() {
            Ok(grade) => break grade,
            Err(_) => say(
                &mut output,
                &format!("  {answer:?} is not a grade; type s, p or f."),
            )?,
        }
    };
    let cause = if grade == Grade::Success {
        None
    } else {
        let menu: Vec<String> = FailureCause::ALL
            .iter()
            .enumerate()
            .map(|(i, c)| format!("{} {c}", i + 1))
            .collect();
        let question = format!(
            "Cause: {}{}? ",
            menu.join(", "),
            if grade == Grade::Partial {
                " (empty for none)"
            } else {
                ""
            }
        );
        loop {
            let answer = ask(&mut input, &mut output, &question)?;
            if answer.is_empty() {
                if grade == Grade::Partial {
                    break None;
                }
                say(&mut output, "  a failure needs a cause.")?;
                continue;
            }
            let by_number = answer
                .parse::<usize>()
                .ok()
                .and_then(|i| i.checked_sub(1))
                .and_then(|i| FailureCause::ALL.get(i).copied());
            match by_number.map_or_else(|| answer.parse::<FailureCause>(), Ok) {
                Ok(cause) => break Some(cause),
                Err(_) => say(
                    &mut output,
                    &format!("  {answer:?} is not a cause; type 1-5 or a name."),
                )?,
            }
        }
    };
    let note = ask(&mut input, &mut output, "Note (empty for none)? ")?;
    let grading = Grading::new(grade, cause, Some(note))?;
    say(&mut output, &format!("  graded {grading}"))?;
    Ok(grading)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn prompt(script: &str) -> (Result<Grading, TrialError>, String) {
        let mut out = Vec::new();
        let result = prompt_grade(script.as_bytes(), &mut out);
        (result, String::from_utf8(out).unwrap())
    }

    #[test]
    fn grade_and_cause_strings_round_trip() {
        for g in Grade::ALL {
            assert_eq!(g.to_string().parse::<Grade>().unwrap(), g);
            assert_eq!(serde_json::to_string(&g).unwrap(), format!("\"{g}\""));
        }
        for c in FailureCause::ALL {
            assert_eq!(c.to_string().parse::<FailureCause>().unwrap(), c);
            assert_eq!(serde_json::to_string(&c).unwrap(), format!("\"{c}\""));
        }
        assert_eq!("F".parse::<Grade>().unwrap(), Grade::Failure);
        assert_eq!(
            "Shape dissimilarity".parse::<FailureCause>().unwrap(),
            FailureCause::ShapeDissimilarity
        );
        assert_eq!(
            "shape_dissimilarity".parse::<FailureCause>().unwrap(),
            FailureCause::ShapeDissimilarity
        );
        assert!(matches!(
            "sucess".parse::<Grade>(),
            Err(TrialError::InvalidGrade { .. })
        ));
        assert!(matches!(
            "gravity".parse::<FailureCause>(),
            Err(TrialError::InvalidCause { .. })
        ));
        assert_eq!(
            [Grade::Success, Grade::Partial, Grade::Failure].map(Grade::score),
            [1, 0, -1]
        );
    }

    #[test]
    fn grading_rules() {
        assert!(matches!(
            Grading::new(Grade::Failure, None, None),
            Err(TrialError::CauseRequired)
        ));
        assert!(matches!(
            Grading::new(Grade::Success, Some(FailureCause::Other), None),
            Err(TrialError::CauseOnSuccess { .. })
        ));
        let g = Grading::new(Grade::Partial, None, Some("  ".into())).unwrap();
        assert_eq!(g.note, None);
        let g = Grading::parse("p", Some(""), Some(" slipped ".into())).unwrap();
        assert_eq!(
            (g.grade, g.cause, g.note.as_deref()),
            (Grade::Partial, None, Some("slipped"))
        );
    }

    #[test]
    fn prompt_success_asks_no_cause() {
        let (g, out) = prompt("s\nclean lift\n");
        let g = g.unwrap();
        assert_eq!(
            g,
            Grading::new(Grade::Success, None, Some("clean lift".into())).unwrap()
        );
        assert!(!out.contains("Cause"));
    }

    #[test]
    fn prompt_failure_reasks_until_valid() {
        let (g, out) = prompt("x\nF\n\n9\nshape dissimilarity\n\n");
        let g = g.unwrap();
        assert_eq!(g.grade, Grade::Failure);
        assert_eq!(g.cause, Some(FailureCause::ShapeDissimilarity));
        assert_eq!(g.note, None);
        assert!(out.contains("\"x\" is not a grade"));
        assert!(out.contains("a failure needs a cause"));
        assert!(out.contains("\"9\" is not a cause"));
    }

    #[test]
    fn prompt_partial_by_number_and_without_cause() {
        let (g, _) = prompt("p\n2\nhandle only\n");
        assert_eq!(g.unwrap().cause, Some(FailureCause::Registration));
        let (g, _) = prompt("partial\n\n\n");
        assert_eq!(
            g.unwrap(),
            Grading::new(Grade::Partial, None, None).unwrap()
        );
    }

    #[test]
    fn prompt_end_of_input_aborts() {
        for script in ["", "f\n", "f\n1\n", "s"] {
            let (g, _) = prompt(script);
            assert!(matches!(g, Err(TrialError::PromptAborted)), "{script:?}");
        }
    }
}
