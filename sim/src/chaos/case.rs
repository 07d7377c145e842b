//! A case file: a run's event list as JSON lines, with a header that says what it is.
//! Lines starting with `#` are comments (what was found, and how to replay it). The
//! test run replays every case in `sim/tests/chaos/`: each was a violation once and
//! must not be one again.
//!
//! ```text
//! # rule 1 broken at 12.345 s: ...
//! {"duration_ms":14345,"seed":7,"rule":1}
//! {"at_ms":2500,"event":{"Estop":{"pressed":true}}}
//! ```

use serde::{Deserialize, Serialize};

use super::Timed;

/// The header line.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Header {
    /// How long the replay runs.
    pub duration_ms: u64,
    /// The seed the events came from (before shrinking), if any.
    pub seed: Option<u64>,
    /// The rule the case once broke.
    pub rule: Option<u8>,
}

/// A case: its header, comments and events.
#[derive(Debug, Clone, PartialEq)]
pub struct Case {
    pub comments: Vec<String>,
    pub header: Header,
    pub events: Vec<Timed>,
}

impl Case {
    pub fn to_text(&self) -> String {
        let mut text = String::new();
        for comment in &self.comments {
            for line in comment.lines() {
                text.push_str("# ");
                text.push_str(line);
                text.push('\n');
            }
        }
        text.push_str(&serde_json::to_string(&self.header).unwrap_or_default());
        text.push('\n');
        for timed in &self.events {
            text.push_str(&serde_json::to_string(timed).unwrap_or_default());
            text.push('\n');
        }
        text
    }

    /// Reads a case; the error names the line that is wrong.
    pub fn parse(text: &str) -> Result<Case, String> {
        let mut comments = Vec::new();
        let mut header = None;
        let mut events = Vec::new();
        for (number, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() {
                continue;
            }
            if let Some(comment) = line.strip_prefix('#') {
                comments.push(comment.trim().to_owned());
                continue;
            }
            let wrong = |error: serde_json::Error| format!("line {}: {error}", number + 1);
            if header.is_none() {
                header = Some(serde_json::from_str::<Header>(line).map_err(wrong)?);
            } else {
                events.push(serde_json::from_str::<Timed>(line).map_err(wrong)?);
            }
        }
        let header = header.ok_or("no header line (duration_ms, seed, rule)")?;
        if events.windows(2).any(|pair| pair[0].at_ms > pair[1].at_ms) {
            return Err("the events are not in time order".to_owned());
        }
        Ok(Case {
            comments,
            header,
            events,
        })
    }
}
