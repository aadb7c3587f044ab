//! Markdown output of the benchmarks (`dnr bench ... --markdown FILE`): tables, the line that
//! says where and when figures were measured, and sections replaced in place in a page.
//!
//! A section is the text between `<!-- BEGIN KEY -->` and `<!-- END KEY -->` lines. Writing
//! one to a file that holds its markers replaces what is between them and keeps the rest of
//! the file, so `docs/benchmarks.md` is refreshed by running the commands it lists. A file
//! without any section markers (or no file) is written whole: the section and its markers.

use std::fmt::Write as _;
use std::path::Path;
use std::process::Command;

use anyhow::{bail, Context, Result};

/// Column alignment.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Align {
    /// Text columns.
    Left,
    /// Number columns.
    Right,
}

/// A Markdown table built row by row.
#[derive(Clone, Debug)]
pub struct Table {
    header: Vec<String>,
    align: Vec<Align>,
    rows: Vec<Vec<String>>,
}

impl Table {
    /// A table with these columns.
    pub fn new(columns: &[(&str, Align)]) -> Self {
        Table {
            header: columns.iter().map(|c| c.0.to_string()).collect(),
            align: columns.iter().map(|c| c.1).collect(),
            rows: Vec::new(),
        }
    }

    /// Appends a row; missing cells are left empty, extra cells are dropped.
    pub fn row(&mut self, mut cells: Vec<String>) {
        cells.resize(self.header.len(), String::new());
        self.rows.push(cells);
    }

    /// Whether the table has no rows.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// The table as Markdown, one line per row, ending with a newline.
    pub fn render(&self) -> String {
        let line = |cells: &[String]| {
            let cells: Vec<String> = cells.iter().map(|c| c.replace('|', "\\|")).collect();
            format!("| {} |\n", cells.join(" | "))
        };
        let mut out = line(&self.header);
        let rule: Vec<String> = self
            .align
            .iter()
            .map(|a| match a {
                Align::Left => "---".to_string(),
                Align::Right => "---:".to_string(),
            })
            .collect();
        out.push_str(&format!("| {} |\n", rule.join(" | ")));
        for r in &self.rows {
            out.push_str(&line(r));
        }
        out
    }
}

/// `min / median` with `digits` decimals.
pub fn min_median(min: f64, median: f64, digits: usize) -> String {
    format!("{min:.digits$} / {median:.digits$}")
}

/// Where and when a benchmark ran: what a reader needs to compare its figures with others.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Provenance {
    /// UTC date and time the run started, `YYYY-MM-DD HH:MM UTC`.
    pub date: String,
    /// `git describe --always --dirty` of the checkout the command ran in (`unknown` outside
    /// one). Run the benchmarks through `cargo run --release` so the binary is built from it.
    pub commit: String,
    /// CPU model, logical CPUs and memory.
    pub machine: String,
    /// The 1-minute load average when the run started (Linux): above 0.5 or so, other
    /// processes shared the machine.
    pub load: Option<f64>,
}

impl Provenance {
    /// The current machine, checkout and time.
    pub fn now() -> Self {
        Provenance {
            date: utc_now(),
            commit: git_describe().unwrap_or_else(|| "unknown".into()),
            machine: machine(),
            load: load_average(),
        }
    }

    /// One Markdown line: date, commit, machine, load.
    pub fn line(&self) -> String {
        let mut s = format!(
            "Measured {} at commit `{}` on {}",
            self.date, self.commit, self.machine
        );
        if let Some(l) = self.load {
            let _ = write!(s, "; load average {l:.2} at the start");
        }
        s.push('.');
        s
    }
}

/// `YYYY-MM-DD HH:MM UTC` from the system clock.
fn utc_now() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
    let (days, rem) = ((secs / 86_400) as i64, secs % 86_400);
    let (y, m, d) = civil_from_days(days);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02} UTC",
        rem / 3600,
        rem % 3600 / 60
    )
}

/// Gregorian (year, month, day) of a count of days since 1970-01-01 (H. Hinnant's
/// `civil_from_days`).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

fn git_describe() -> Option<String> {
    let out = Command::new("git")
        .args(["describe", "--always", "--dirty", "--abbrev=7"])
        .stderr(std::process::Stdio::null())
        .output()
        .ok()?;
    let s = String::from_utf8(out.stdout).ok()?.trim().to_string();
    (out.status.success() && !s.is_empty()).then_some(s)
}

/// CPU model, logical CPUs and memory, from what the OS tells (on Linux, its proc files).
fn machine() -> String {
    let cpus = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1);
    let cpuinfo = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let model = cpuinfo
        .lines()
        .find_map(|l| {
            let (k, v) = l.split_once(':')?;
            (k.trim() == "model name").then(|| v.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    let mem_gib = std::fs::read_to_string("/proc/meminfo").ok().and_then(|m| {
        let kib: f64 = m
            .lines()
            .find(|l| l.starts_with("MemTotal:"))?
            .split_whitespace()
            .nth(1)?
            .parse()
            .ok()?;
        Some(kib / (1024.0 * 1024.0))
    });
    match mem_gib {
        Some(g) => format!("{model}, {cpus} logical CPUs, {g:.0} GiB"),
        None => format!("{model}, {cpus} logical CPUs"),
    }
}

fn load_average() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg")
        .ok()?
        .split_whitespace()
        .next()?
        .parse()
        .ok()
}

/// The marker lines of section `key`.
fn markers(key: &str) -> (String, String) {
    (
        format!("<!-- BEGIN {key} -->"),
        format!("<!-- END {key} -->"),
    )
}

/// `text` with section `key` set to `body` (see the module documentation); `file` names the
/// file in errors. `text` None: no file yet.
pub fn splice(file: &Path, text: Option<&str>, key: &str, body: &str) -> Result<String> {
    let (begin, end) = markers(key);
    let body = body.trim_end_matches('\n');
    let section = format!("{begin}\n{body}\n{end}\n");
    let Some(text) = text else {
        return Ok(section);
    };
    let lines: Vec<&str> = text.lines().collect();
    let at = |m: &str| lines.iter().position(|l| l.trim() == m);
    match (at(&begin), at(&end)) {
        (Some(b), Some(e)) if b < e => {
            let mut out = String::new();
            for l in &lines[..b] {
                out.push_str(l);
                out.push('\n');
            }
            out.push_str(&section);
            for l in &lines[e + 1..] {
                out.push_str(l);
                out.push('\n');
            }
            Ok(out)
        }
        (None, None) => {
            let others: Vec<&str> = lines
                .iter()
                .filter_map(|l| l.trim().strip_prefix("<!-- BEGIN ")?.strip_suffix(" -->"))
                .collect();
            if others.is_empty() {
                Ok(section)
            } else {
                bail!(
                    "{}: has no section `{key}` (it has: {}); add the lines `{begin}` and `{end}` where it goes, or write to another file",
                    file.display(),
                    others.join(", ")
                )
            }
        }
        _ => bail!(
            "{}: the markers of section `{key}` are unpaired or out of order",
            file.display()
        ),
    }
}

/// The text of `file`, None when there is no such file.
fn read_existing(file: &Path) -> Result<Option<String>> {
    match std::fs::read_to_string(file) {
        Ok(t) => Ok(Some(t)),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(e).with_context(|| file.display().to_string()),
    }
}

/// Checks that section `key` can be written to `file`, before a long measurement whose
/// result would otherwise be lost.
pub fn check_section(file: &Path, key: &str) -> Result<()> {
    splice(file, read_existing(file)?.as_deref(), key, "").map(|_| ())
}

/// Writes section `key` into `file` (see the module documentation): to a temporary file
/// beside it, then renamed over it, so a failure leaves the old file whole.
pub fn write_section(file: &Path, key: &str, body: &str) -> Result<()> {
    let old = read_existing(file)?;
    let new = splice(file, old.as_deref(), key, body)?;
    let name = file
        .file_name()
        .with_context(|| format!("{}: not a file name", file.display()))?;
    let mut tmp_name = name.to_os_string();
    tmp_name.push(format!(".{}.tmp", std::process::id()));
    let tmp = file.with_file_name(tmp_name);
    std::fs::write(&tmp, new).with_context(|| tmp.display().to_string())?;
    std::fs::rename(&tmp, file).with_context(|| {
        let _ = std::fs::remove_file(&tmp);
        format!("renaming {} to {}", tmp.display(), file.display())
    })?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_renders_alignment_and_escapes_pipes() {
        let mut t = Table::new(&[("name", Align::Left), ("ms", Align::Right)]);
        t.row(vec!["a|b".into(), "1.5".into()]);
        t.row(vec!["c".into()]);
        assert_eq!(
            t.render(),
            "| name | ms |\n| --- | ---: |\n| a\\|b | 1.5 |\n| c |  |\n"
        );
        assert_eq!(min_median(1.234, 5.0, 1), "1.2 / 5.0");
    }

    #[test]
    fn civil_dates() {
        assert_eq!(civil_from_days(0), (1970, 1, 1));
        assert_eq!(civil_from_days(11_016), (2000, 2, 29));
        assert_eq!(civil_from_days(20_790), (2026, 12, 3));
        assert_eq!(civil_from_days(-1), (1969, 12, 31));
    }

    #[test]
    fn splice_replaces_between_markers_only() {
        let f = Path::new("page.md");
        let page = "# Page\n\nintro\n<!-- BEGIN t -->\nold\nrows\n<!-- END t -->\n\nafter\n";
        let got = splice(f, Some(page), "t", "new\n").unwrap();
        assert_eq!(
            got,
            "# Page\n\nintro\n<!-- BEGIN t -->\nnew\n<!-- END t -->\n\nafter\n"
        );
        // Twice gives the same page.
        assert_eq!(splice(f, Some(&got), "t", "new").unwrap(), got);
        // No file, or a file without markers: the section alone.
        assert_eq!(
            splice(f, None, "t", "x").unwrap(),
            "<!-- BEGIN t -->\nx\n<!-- END t -->\n"
        );
        assert_eq!(
            splice(f, Some("plain\n"), "t", "x").unwrap(),
            "<!-- BEGIN t -->\nx\n<!-- END t -->\n"
        );
    }

    #[test]
    fn splice_refuses_a_page_without_this_section() {
        let f = Path::new("page.md");
        let page = "<!-- BEGIN a -->\n1\n<!-- END a -->\n";
        let e = splice(f, Some(page), "b", "x").unwrap_err().to_string();
        assert!(e.contains("page.md") && e.contains("section `b`") && e.contains("it has: a"));
        let e = splice(f, Some("<!-- END b -->\n<!-- BEGIN b -->\n"), "b", "x")
            .unwrap_err()
            .to_string();
        assert!(e.contains("unpaired or out of order"), "{e}");
    }

    #[test]
    fn check_section_refuses_before_a_run_what_writing_would_refuse() {
        let dir = std::env::temp_dir().join(format!("dnr-md-check-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("page.md");
        check_section(&f, "k").unwrap(); // no file yet: it will be created
        std::fs::write(&f, "<!-- BEGIN other -->\n<!-- END other -->\n").unwrap();
        assert!(check_section(&f, "k").is_err());
        check_section(&f, "other").unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn write_section_keeps_the_rest_of_the_file() {
        let dir = std::env::temp_dir().join(format!("dnr-md-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("page.md");
        std::fs::write(&f, "top\n<!-- BEGIN k -->\nold\n<!-- END k -->\nbottom\n").unwrap();
        write_section(&f, "k", "| a |\n").unwrap();
        assert_eq!(
            std::fs::read_to_string(&f).unwrap(),
            "top\n<!-- BEGIN k -->\n| a |\n<!-- END k -->\nbottom\n"
        );
        // Only the page is left: the temporary file was renamed over it.
        assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
