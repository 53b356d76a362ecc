//! The report page's fixed parts: style, the error catcher that runs
//! first, the filter script, and HTML escaping. No external resource: the
//! page works from a file with no network.
//!
//! Errors: a script error or `console.error` adds a `<pre class="js-error">`
//! to the page (so `chromium --dump-dom` shows it) and the filter script
//! sets `data-report-ready="1"` on `<body>` when it has run to its end;
//! scripts/report_check.sh requires the marker and no `js-error`.

/// Escapes text for HTML content and attribute values.
pub fn esc(s: &str) -> String {
    super::super::junit::xml_escape(s)
}

/// The page head: title, style, and the error catcher (before any other script).
pub fn head(title: &str) -> String {
    format!(
        r#"<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<script>
(function () {{
  function record(msg) {{
    var p = document.createElement("pre");
    p.className = "js-error";
    p.textContent = msg;
    (document.body || document.documentElement).appendChild(p);
  }}
  window.addEventListener("error", function (e) {{
    record("error: " + e.message + " at " + e.filename + ":" + e.lineno);
  }});
  window.addEventListener("unhandledrejection", function (e) {{
    record("unhandled rejection: " + e.reason);
  }});
  var ce = console.error;
  console.error = function () {{
    record("console.error: " + Array.prototype.join.call(arguments, " "));
    ce.apply(console, arguments);
  }};
}})();
</script>
<style>
body {{ font: 14px/1.4 system-ui, sans-serif; margin: 1.5em; color: #222; }}
h1 {{ font-size: 1.5em; }} h2 {{ font-size: 1.2em; margin-top: 1.5em; }}
table {{ border-collapse: collapse; }}
td, th {{ border: 1px solid #ddd; padding: 2px 6px; text-align: left; vertical-align: top; }}
th {{ background: #f3f3f3; }}
.v-PASS {{ background: #d8f5d8; }} .v-FAIL {{ background: #f9c9c9; }}
.v-ERROR {{ background: #f5b3f0; }} .v-TIMEOUT {{ background: #fbdcae; }} .v-SKIP {{ background: #e6e6e6; }}
.num {{ text-align: right; font-variant-numeric: tabular-nums; }}
code, pre {{ font-size: 12px; }} pre {{ white-space: pre-wrap; }}
.filters label {{ margin-right: 1em; }}
.triple {{ display: flex; gap: 8px; align-items: flex-start; margin: 6px 0; }}
.triple figure {{ margin: 0; }} .triple img {{ image-rendering: pixelated; width: 192px; }}
.bar {{ height: 12px; width: 192px; }} .barlabels {{ display: flex; justify-content: space-between; width: 192px; font-size: 11px; }}
.plots {{ display: flex; flex-wrap: wrap; gap: 12px; }} .plots figure {{ margin: 0; }}
.plots img, .plots svg {{ max-width: 640px; border: 1px solid #ddd; }}
.js-error {{ color: #b00; font-weight: bold; }}
</style></head><body>
"#,
        title = esc(title)
    )
}

/// The filter script and the ready marker; goes last in `<body>`.
pub const SCRIPT: &str = r#"<script>
(function () {
  var ids = ["f-verdict", "f-renderer", "f-backend", "f-text"];
  function val(id) { return document.getElementById(id).value; }
  function apply() {
    var v = val("f-verdict"), r = val("f-renderer"), b = val("f-backend");
    var q = val("f-text").toLowerCase(), shown = 0;
    var rows = document.querySelectorAll("tbody.result");
    for (var i = 0; i < rows.length; i++) {
      var d = rows[i].dataset;
      var ok = (!v || d.verdict === v) && (!r || d.renderer === r) &&
               (!b || d.backend === b) && (!q || d.case.toLowerCase().indexOf(q) >= 0);
      rows[i].style.display = ok ? "" : "none";
      if (ok) shown++;
    }
    document.getElementById("shown").textContent = String(shown);
  }
  for (var i = 0; i < ids.length; i++) {
    document.getElementById(ids[i]).addEventListener("input", apply);
  }
  apply();
  document.body.setAttribute("data-report-ready", "1");
})();
</script>
</body></html>
"#;

/// A `<select>` filter over `values` (first option: all).
pub fn select(id: &str, label: &str, values: &[String]) -> String {
    let mut s = format!(
        "<label>{} <select id=\"{id}\"><option value=\"\">all</option>",
        esc(label)
    );
    for v in values {
        s += &format!("<option value=\"{0}\">{0}</option>", esc(v));
    }
    s + "</select></label>"
}

/// A two-column table of key/value rows.
pub fn kv_table(rows: &[(String, String)]) -> String {
    let mut s = String::from("<table>");
    for (k, v) in rows {
        s += &format!("<tr><th>{}</th><td>{}</td></tr>", esc(k), esc(v));
    }
    s + "</table>"
}

/// A number for a table cell: 4 significant digits, `-` for none.
pub fn num(v: Option<f64>) -> String {
    match v {
        None => "-".to_string(),
        Some(x) if x == 0.0 || (1e-3..1e5).contains(&x.abs()) => {
            format!("{}", (x * 1e4).round() / 1e4)
        }
        Some(x) => format!("{x:.3e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn escaping_keeps_markup_out_of_the_page() {
        assert_eq!(
            esc("<a href=\"x\">&'"),
            "&lt;a href=&quot;x&quot;&gt;&amp;&apos;"
        );
        assert!(select("f", "v", &["<b>".into()]).contains("&lt;b&gt;"));
    }

    #[test]
    fn numbers_are_short_and_none_is_a_dash() {
        assert_eq!(num(None), "-");
        assert_eq!(num(Some(0.5)), "0.5");
        assert_eq!(num(Some(1.23456e-7)), "1.235e-7");
        assert_eq!(num(Some(0.0)), "0");
    }
}
