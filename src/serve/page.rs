//! The HTML of the grading page and the report page (also written as a static
//! page by `cell report --html`). Every text from the log is escaped.

use crate::trial::report::Report;
use crate::trial::{FailureCause, GradeEvent, TrialRecord};
use std::fmt::Write as _;

/// Escapes `&`, `<`, `>`, `"` and `'` for HTML text and attribute values.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

const STYLE: &str = "body{font-family:sans-serif;margin:1.5em;color:#222}\
table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:4px 8px;text-align:right}\
th:first-child,td:first-child{text-align:left}\
.trial{border:1px solid #ccc;border-radius:6px;padding:10px;margin:12px 0}\
.trial img{max-width:100%;display:block;margin:6px 0}\
.success{color:#2e8b57}.partial{color:#c77f00}.failure{color:#c82828}\
button{font-size:1em;margin-right:6px}nav a{margin-right:1em}";

fn head(title: &str) -> String {
    format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>{}</title><style>{STYLE}</style></head><body>\n",
        escape(title)
    )
}

/// One trial as the pages show it.
pub struct TrialView<'a> {
    /// The log row.
    pub record: &'a TrialRecord,
    /// Where the page finds its picture (`None`: no picture).
    pub picture_src: Option<String>,
    /// The grade history, oldest first.
    pub history: &'a [GradeEvent],
}

fn grade_text(record: &TrialRecord) -> String {
    match &record.grading {
        Some(g) => format!(
            "<span class=\"{}\" data-grade=\"{}\">{}</span>",
            g.grade,
            g.grade,
            escape(&g.to_string())
        ),
        None => "<span data-grade=\"\">ungraded</span>".to_string(),
    }
}

fn trial_summary(out: &mut String, view: &TrialView<'_>) {
    let r = view.record;
    let t = &r.trial;
    let _ = write!(
        out,
        "<h3>Trial {id}: {cat} / {task}, method {method}</h3>\
         <p>object {obj}, placement {pl}, campaign {camp}, started {at}; grade: {grade}</p>",
        id = r.id,
        cat = escape(&t.category),
        task = escape(&t.task),
        method = escape(&t.method),
        obj = escape(&t.object.name),
        pl = t.placement.index,
        camp = escape(t.campaign_id.as_deref().unwrap_or("-")),
        at = t.started_at,
        grade = grade_text(r),
    );
    match &view.picture_src {
        Some(src) => {
            let _ = write!(
                out,
                "<img id=\"picture-{}\" src=\"{}\" alt=\"picture of trial {}\">",
                r.id,
                escape(src),
                r.id
            );
        }
        None => out.push_str("<p><em>no picture</em></p>"),
    }
}

/// The grading page: every trial with its picture, the grade buttons and the cause.
/// `token` is put into each form (the page was opened with it); `action` is where
/// the forms post.
pub fn grading_page(
    title: &str,
    trials: &[TrialView<'_>],
    token: &str,
    action: &str,
    message: Option<&str>,
) -> String {
    let mut out = head(title);
    let _ = write!(
        out,
        "<h1>{}</h1><nav><a href=\"/?token={tok}\">trials</a><a href=\"/report\">report</a></nav>",
        escape(title),
        tok = escape(token)
    );
    if let Some(m) = message {
        let _ = write!(out, "<p id=\"message\"><strong>{}</strong></p>", escape(m));
    }
    if trials.is_empty() {
        out.push_str("<p>No trials.</p>");
    }
    for view in trials {
        let id = view.record.id;
        let _ = write!(out, "<div class=\"trial\" id=\"trial-{id}\">");
        trial_summary(&mut out, view);
        let _ = write!(
            out,
            "<form method=\"post\" action=\"{action}\" id=\"form-{id}\">\
             <input type=\"hidden\" name=\"trial\" value=\"{id}\">\
             <input type=\"hidden\" name=\"token\" value=\"{tok}\">\
             <label>cause <select name=\"cause\" id=\"cause-{id}\"><option value=\"\">(none)</option>",
            action = escape(action),
            tok = escape(token),
        );
        let current = view.record.grading.as_ref().and_then(|g| g.cause);
        for cause in FailureCause::ALL {
            let _ = write!(
                out,
                "<option value=\"{c}\"{sel}>{c}</option>",
                c = cause.as_str(),
                sel = if current == Some(cause) {
                    " selected"
                } else {
                    ""
                }
            );
        }
        let _ = write!(
            out,
            "</select></label> <label>note <input type=\"text\" name=\"note\" id=\"note-{id}\" maxlength=\"500\"></label><br>\
             <button type=\"submit\" name=\"grade\" value=\"success\" id=\"success-{id}\">success</button>\
             <button type=\"submit\" name=\"grade\" value=\"partial\" id=\"partial-{id}\">partial</button>\
             <button type=\"submit\" name=\"grade\" value=\"failure\" id=\"failure-{id}\">failure</button></form>"
        );
        if !view.history.is_empty() {
            let _ = write!(
                out,
                "<details><summary>history ({})</summary><ol>",
                view.history.len()
            );
            for e in view.history {
                let _ = write!(
                    out,
                    "<li>{} by {}: {}</li>",
                    e.graded_at,
                    e.source,
                    escape(&e.grading.to_string())
                );
            }
            out.push_str("</ol></details>");
        }
        out.push_str("</div>\n");
    }
    out.push_str("</body></html>\n");
    out
}

fn pct(p: Option<f64>) -> String {
    p.map_or("-".to_string(), |p| format!("{p:.1}"))
}

/// The report page: rates per method, failures by cause (Table 2) next to the
/// paper's, the sign tests, the charts (`chart_srcs`: outcomes, causes) and, when
/// given, every trial with its picture.
pub fn report_page(report: &Report, chart_srcs: [&str; 2], trials: &[TrialView<'_>]) -> String {
    let scope = report
        .campaign_id
        .as_deref()
        .map_or("every trial".to_string(), |c| format!("campaign {c}"));
    let mut out = head(&format!("graspcell report: {scope}"));
    let _ = write!(
        out,
        "<h1>Report: {}</h1><p>{} trials, {} graded, {} ungraded.</p>",
        escape(&scope),
        report.trials,
        report.graded,
        report.ungraded
    );
    out.push_str(
        "<h2>Outcomes per method</h2><table id=\"outcomes\"><tr><th>method</th><th>trials</th>\
         <th>graded</th><th>success %</th><th>partial %</th><th>failure %</th></tr>",
    );
    for m in &report.methods {
        let _ = write!(
            out,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            escape(&m.method),
            m.trials,
            m.graded,
            pct(m.success_pct),
            pct(m.partial_pct),
            pct(m.failure_pct)
        );
    }
    out.push_str("</table>");
    let table = &report.failure_causes;
    out.push_str(
        "<h2>Failures by cause, % of all graded grasps (the paper's Table 2)</h2>\
         <table id=\"table2\"><tr><th>cause</th>",
    );
    for m in &table.methods {
        let _ = write!(out, "<th>{}</th>", escape(m));
    }
    out.push_str("</tr>");
    for row in table.rows.iter().chain(std::iter::once(&table.total)) {
        let _ = write!(out, "<tr><td>{}</td>", escape(&row.cause));
        for (count, p) in row.counts.iter().zip(&row.percent) {
            let _ = write!(out, "<td>{} ({count})</td>", pct(*p));
        }
        out.push_str("</tr>");
    }
    out.push_str("</table>");
    let _ = write!(
        out,
        "<h3>Next to the paper (ours / paper)</h3><pre>{}</pre>",
        escape(&crate::trial::paper::comparison_text(report))
    );
    if !report.sign_tests.is_empty() {
        out.push_str("<h2>Paired sign tests</h2><pre>");
        for c in &report.sign_tests {
            let _ = writeln!(
                out,
                "{}",
                escape(&format!(
                    "{} vs {}: {}",
                    c.a,
                    c.b,
                    serde_json::to_string(&c.test).unwrap_or_default()
                ))
            );
        }
        out.push_str("</pre>");
    }
    let _ = write!(
        out,
        "<h2>Charts</h2><img id=\"chart-outcomes\" src=\"{}\" alt=\"outcomes per method\">\
         <img id=\"chart-causes\" src=\"{}\" alt=\"failures by cause\">",
        escape(chart_srcs[0]),
        escape(chart_srcs[1])
    );
    if !trials.is_empty() {
        out.push_str("<h2>Trials</h2>");
        for view in trials {
            let _ = write!(out, "<div class=\"trial\" id=\"trial-{}\">", view.record.id);
            trial_summary(&mut out, view);
            out.push_str("</div>\n");
        }
    }
    out.push_str("</body></html>\n");
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escape_neutralises_markup() {
        assert_eq!(
            escape("<script>alert('x') & \"y\"</script>"),
            "&lt;script&gt;alert(&#39;x&#39;) &amp; &quot;y&quot;&lt;/script&gt;"
        );
    }
}
