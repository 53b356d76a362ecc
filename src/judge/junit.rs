//! JUnit XML for CI systems: one `<testcase>` per case and backend.

use super::scoreboard::{Scoreboard, Verdict};

/// Escapes text for XML attributes and content.
pub fn xml_escape(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&apos;"),
            c if (c as u32) < 0x20 && c != '\n' && c != '\t' => o.push(' '),
            c => o.push(c),
        }
    }
    o
}

/// The scoreboard as a JUnit XML document.
pub fn to_junit(b: &Scoreboard) -> String {
    let mut cases = String::new();
    let (mut n, mut fails, mut errs, mut skips) = (0, 0, 0, 0);
    for c in &b.cases {
        for r in &c.results {
            n += 1;
            let name = xml_escape(&format!("{} [{}]", c.id, r.backend.name()));
            let class = xml_escape(&c.op);
            let expected_ok = c.expect.is_some_and(|e| r.verdict.matches(e));
            let detail = if !r.reason.is_empty() {
                r.reason.clone()
            } else {
                r.checks
                    .iter()
                    .filter(|k| !k.passed)
                    .map(|k| format!("{}: {}", k.assertion, k.message))
                    .collect::<Vec<_>>()
                    .join("\n")
            };
            let body = match r.verdict {
                _ if expected_ok => String::new(),
                Verdict::Pass if c.expect.is_none() => String::new(),
                Verdict::Skip if c.expect.is_none() => {
                    skips += 1;
                    format!("<skipped message=\"{}\"/>", xml_escape(&detail))
                }
                Verdict::Error | Verdict::Timeout => {
                    errs += 1;
                    format!(
                        "<error message=\"{}\">{}</error>",
                        r.verdict.name(),
                        xml_escape(&detail)
                    )
                }
                v => {
                    fails += 1;
                    format!(
                        "<failure message=\"{}\">{}</failure>",
                        v.name(),
                        xml_escape(&detail)
                    )
                }
            };
            cases += &format!("    <testcase name=\"{name}\" classname=\"{class}\" time=\"{:.3}\">{body}</testcase>\n", r.wall_s);
        }
    }
    format!(
        "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<testsuites>\n  <testsuite name=\"hpjudge\" tests=\"{n}\" failures=\"{fails}\" errors=\"{errs}\" skipped=\"{skips}\">\n{cases}  </testsuite>\n</testsuites>\n"
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escapes_markup() {
        assert_eq!(xml_escape("a<b & \"c\""), "a&lt;b &amp; &quot;c&quot;");
    }
}
