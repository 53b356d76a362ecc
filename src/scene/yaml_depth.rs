//! A linear pre-scan of YAML text that refuses deep nesting before the
//! parser sees it: nested brackets made the parser's refusal quadratic in the
//! file (27 s for 200 KB), this scan is one pass.

/// Deepest nesting accepted (flow brackets plus block indentation levels);
/// hotpath's files nest under 10.
pub const MAX_YAML_DEPTH: usize = 64;

/// The deepest nesting in `text`, counting `[`/`{` outside quotes and
/// comments, block indentation levels and `- ` sequence entries; stops
/// counting once past `limit`.
pub fn nesting_depth(text: &str, limit: usize) -> usize {
    let mut max = 0usize;
    let mut flow = 0usize;
    let mut indents: Vec<usize> = Vec::new();
    for line in text.lines() {
        let mut block = 0usize;
        if flow == 0 {
            let indent = line.len() - line.trim_start_matches(' ').len();
            let rest = &line[indent..];
            if !rest.is_empty() && !rest.starts_with('#') {
                while indents.last().is_some_and(|&i| i >= indent) {
                    indents.pop();
                }
                indents.push(indent);
                let mut r = rest;
                let mut dashes = 0usize;
                while let Some(x) = r.strip_prefix("- ") {
                    dashes += 1;
                    r = x.trim_start_matches(' ');
                }
                block = indents.len() + dashes;
            }
        }
        let mut quote: Option<char> = None;
        let mut prev = ' ';
        let mut escaped = false;
        for c in line.chars() {
            match quote {
                Some('"') if escaped => escaped = false,
                Some('"') if c == '\\' => escaped = true,
                Some(q) if c == q => quote = None,
                Some(_) => {}
                None => match c {
                    '#' if prev == ' ' || prev == '\t' => break,
                    '\'' | '"' if matches!(prev, ' ' | '\t' | '[' | '{' | ',' | ':') => {
                        quote = Some(c)
                    }
                    '[' | '{' => {
                        flow += 1;
                        max = max.max(block + flow);
                    }
                    ']' | '}' => flow = flow.saturating_sub(1),
                    _ => {}
                },
            }
            prev = c;
        }
        max = max.max(block + flow);
        if max > limit {
            return max;
        }
    }
    max
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flow_block_and_sequence_nesting_count() {
        assert_eq!(nesting_depth("a: 1\nb: [1, 2]\n", 64), 2);
        assert_eq!(nesting_depth("a:\n  b:\n    c: {d: [1]}\n", 64), 5);
        assert_eq!(nesting_depth("- - - x\n", 64), 4);
        assert_eq!(nesting_depth("a: '[[[[' # [[[[\nb: \"{{\\\"{{\"\n", 64), 1);
    }

    #[test]
    fn deep_brackets_are_counted_in_one_pass() {
        let deep = "[".repeat(100_000) + &"]".repeat(100_000);
        let t = std::time::Instant::now();
        assert!(nesting_depth(&deep, MAX_YAML_DEPTH) > MAX_YAML_DEPTH);
        assert!(t.elapsed().as_secs_f64() < 0.5);
    }

    #[test]
    fn committed_yaml_files_nest_well_under_the_limit() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut files = vec![
            root.join("thresholds.yaml"),
            root.join("perf_scenarios.yaml"),
        ];
        for d in ["TESTS", "TESTS/scenes"] {
            for e in std::fs::read_dir(root.join(d)).unwrap().flatten() {
                let p = e.path();
                if p.is_dir() {
                    files.push(p.join("manifest.yaml"));
                } else if p.extension().is_some_and(|x| x == "yaml") {
                    files.push(p);
                }
            }
        }
        for f in files.iter().filter(|f| f.is_file()) {
            let text = std::fs::read_to_string(f).unwrap();
            let d = nesting_depth(&text, MAX_YAML_DEPTH);
            assert!(d <= 16, "{}: depth {d}", f.display());
        }
    }
}
