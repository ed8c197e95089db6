//! Defect specifications: the shipped paper table, and errors naming the field.

use synosis::defect::{DefectError, DefectSpec};

#[test]
fn shipped_paper_spec_equals_the_built_in_default() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/defects-paper.toml");
    let spec = DefectSpec::load(&path).unwrap();
    assert_eq!(spec, DefectSpec::paper());
    assert_eq!(spec.count(), 12);
    let q: Vec<u32> = spec
        .dent
        .iter()
        .map(|d| d.quantity)
        .chain(spec.scratch.iter().map(|s| s.quantity))
        .collect();
    assert_eq!(q, vec![5, 3, 2, 2]);
    // Dents carry the paper's measured rim (peak as high as the dent is deep), also when
    // a spec file leaves `rim_height` out.
    assert!(
        spec.dent
            .iter()
            .all(|d| d.rim_height.min == 1.0 && d.rim_height.max == 1.0)
    );
    let dflt = DefectSpec::from_toml_str(
        "[[dent]]\nname = \"d\"\nquantity = 1\ndiameter_mm = 0.1\nelongation = 1\ndepth = 0.1\n",
        "spec.toml",
    )
    .unwrap();
    assert_eq!(
        (dflt.dent[0].rim_height.min, dflt.dent[0].rim_height.max),
        (1.0, 1.0)
    );
}

fn err(text: &str) -> String {
    match DefectSpec::from_toml_str(text, "spec.toml") {
        Ok(_) => panic!("accepted: {text}"),
        Err(e) => e.to_string(),
    }
}

const DENT: &str =
    "[[dent]]\nname = \"d\"\nquantity = 1\nelongation = [1, 2]\ndepth = [0.1, 0.2]\n";

#[test]
fn bad_specs_name_the_field_and_the_allowed_range() {
    let e = err(&format!("{DENT}diameter_mm = [0.3, 0.1]\n"));
    assert!(
        e.contains("dent[0] (d).diameter_mm") && e.contains("min must not exceed max"),
        "{e}"
    );
    let e = err(&format!("{DENT}diameter_mm = [0.1, 50]\n"));
    assert!(e.contains("diameter_mm") && e.contains("20"), "{e}");
    let e = err(&DENT
        .replace("elongation = [1, 2]", "elongation = 0.5")
        .replace("depth", "diameter_mm = 0.1\ndepth"));
    assert!(
        e.contains("elongation") && e.contains("allowed within 1"),
        "{e}"
    );
    let e = err(&format!("{DENT}diameter_mm = 0.1\ncolour = 3\n"));
    assert!(e.contains("colour"), "unknown field must be named: {e}");
    let e = err("faces = [\"D\"]\n");
    assert!(e.contains("faces[0]"), "{e}");
    let e = err("resolution = 1000\n");
    assert!(e.contains("resolution") && e.contains("64"), "{e}");
    let e = err(
        "[[scratch]]\nname = \"s\"\nquantity = 1\nwidth_mm = 0.1\npath_length_mm = 5\nstep_mm = 0.1\ncurviness_deg = [0, 500]\n",
    );
    assert!(
        e.contains("scratch[0] (s).curviness_deg") && e.contains("180"),
        "{e}"
    );
    let e = err(
        "[[scratch]]\nname = \"s\"\nquantity = 1\nwidth_mm = 0.1\npath_length_mm = 5\ncurviness_deg = 1\n",
    );
    assert!(e.contains("step_mm"), "missing field must be named: {e}");
    let e = err(&format!("{DENT}diameter_mm = \"big\"\n"));
    assert!(e.contains("diameter_mm"), "{e}");
    // Errors are the typed kinds a caller can match.
    assert!(matches!(
        DefectSpec::from_toml_str("resolution = 1", "x"),
        Err(DefectError::Spec { .. })
    ));
    assert!(matches!(
        DefectSpec::from_toml_str("nope = 1", "x"),
        Err(DefectError::Parse { .. })
    ));
}
