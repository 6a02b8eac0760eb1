//! The README's attribute and output tables, generated from the plugin's own tables
//! ([`tacrom::attributes`], [`tacrom::sensor::outputs`]): `tacrom doc-tables --write`
//! rewrites the lines between each pair of markers, and a test checks that the committed
//! README matches.

/// One generated block: its marker name and its contents.
fn blocks() -> [(&'static str, String); 2] {
    [
        ("attributes", tacrom::attributes::markdown_table()),
        ("outputs", tacrom::sensor::outputs::markdown_table()),
    ]
}

/// `text` with each generated block between `<!-- tacrom:NAME:begin -->` and
/// `<!-- tacrom:NAME:end -->` replaced by the table; an error names a marker that is
/// missing, repeated or out of order.
pub fn splice(text: &str) -> Result<String, String> {
    let mut out = text.to_owned();
    for (name, table) in blocks() {
        let begin = format!("<!-- tacrom:{name}:begin -->");
        let end = format!("<!-- tacrom:{name}:end -->");
        let (Some(b), Some(e)) = (out.find(&begin), out.find(&end)) else {
            return Err(format!("the markers {begin} and {end} are not both there"));
        };
        if out.matches(&begin).count() != 1 || out.matches(&end).count() != 1 || e < b {
            return Err(format!("{begin} ... {end}: each once, in that order"));
        }
        let start = b + begin.len();
        out.replace_range(start..e, &format!("\n{table}"));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_block_is_replaced_and_the_rest_kept() {
        let text =
            "intro\n<!-- tacrom:attributes:begin -->\nstale row\n<!-- tacrom:attributes:end \
                    -->\nmiddle\n<!-- tacrom:outputs:begin --><!-- tacrom:outputs:end -->\nend\n";
        let out = splice(text).unwrap();
        assert!(out.starts_with("intro\n<!-- tacrom:attributes:begin -->\n| attribute |"));
        assert!(!out.contains("stale row"));
        assert!(
            out.contains("| `young` | Young's modulus of the gel | Pa | `1.19e5` | [100, 1e10] |")
        );
        assert!(out.contains("| `depth` | (H, W) | m |"));
        assert!(out.ends_with("<!-- tacrom:outputs:end -->\nend\n"));
        assert_eq!(splice(&out).unwrap(), out, "splicing is idempotent");
    }

    #[test]
    fn missing_or_repeated_markers_are_refused() {
        assert!(splice("no markers").is_err());
        let twice = "<!-- tacrom:attributes:begin --><!-- tacrom:attributes:end -->\
                     <!-- tacrom:attributes:begin --><!-- tacrom:outputs:begin -->\
                     <!-- tacrom:outputs:end -->";
        assert!(splice(twice).is_err());
    }
}
