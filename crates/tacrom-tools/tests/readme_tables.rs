//! The README's attribute and output tables are the plugin's own tables: a change to an
//! attribute's default, range or meaning, or to an output, that is not carried into the
//! README fails here (`cargo run --release --bin tacrom -- doc-tables --write` mends it).

#[test]
fn the_readme_tables_match_the_attribute_and_output_tables() {
    let path = tacrom::checkout_root().join("README.md");
    let readme = std::fs::read_to_string(&path).expect("README.md is readable");
    let expected = tacrom_tools::doc_tables::splice(&readme).expect("README.md has the markers");
    assert!(
        readme == expected,
        "README.md's tables differ from the code's; run `tacrom doc-tables --write`"
    );
}
