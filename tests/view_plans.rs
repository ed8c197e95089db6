//! Dataset viewpoints besides `views` (docs/dataset.md): generated plans (cone, ring)
//! and `[[pose]]` entries expand into images like views, with stable names and seeds.

use synosis::dataset::job::{GOLDEN_ANGLE_DEG, Job, Viewpoint};
use synosis::dataset::plan::expand;
use synosis::scene::config::parse_view;

fn job(viewpoints: &str) -> Result<Job, String> {
    let text = format!(
        r#"
seed = 3
{viewpoints}
[render]
width = 32
height = 24
spp = 1
bounces = 1
[texture]
size_px = 80
spacing_um = 400.0
[[finish]]
name = "sandblasted-2.5bar"
kind = "sandblasted"
textures = 1
[[object]]
name = "body"
mesh = "testbody-b"
defective = 0
defect_free = 2
"#
    );
    Job::parse(&text, "job.toml", std::path::Path::new(".")).map_err(|e| e.to_string())
}

#[test]
fn plans_and_poses_expand_after_the_views() {
    let j = job(r#"
views = ["B10"]
plan = { cone = { face = "A", max_tilt_deg = 20, count = 9 }, ring = { face = "C", tilt_deg = 15, count = 4 } }
[[pose]]
name = "top"
look_at = { eye = [0, 0, 150], target = [0, 0, 0], up = [0, 1, 0] }
[[pose]]
name = "robot-3"
opencv = { rvec = [3.14159, 0, 0], tvec = [0, 0, 150] }
"#)
    .unwrap();
    let vps = j.viewpoints();
    let names: Vec<&str> = vps.iter().map(|v| v.name()).collect();
    assert_eq!(names.len(), 1 + 9 + 4 + 2);
    assert_eq!(names[0], "B10");
    assert_eq!(names[1], "A0", "the cone starts on the normal");
    assert_eq!(&names[10..14], ["C15", "C15@90", "C15@180", "C15@270"]);
    assert_eq!(&names[14..], ["top", "robot-3"]);
    assert!(matches!(vps[15], Viewpoint::Pose(p) if p.opencv.is_some()));
    // The cone: equal solid angle per view up to the maximum tilt, golden-angle azimuths.
    let cmax = 20f64.to_radians().cos();
    for (k, n) in names[1..10].iter().enumerate() {
        let v = parse_view(n).unwrap();
        assert_eq!(v.face, 1);
        let want = (1.0 - (1.0 - cmax) * k as f64 / 8.0).acos().to_degrees();
        assert!((v.angle_deg as f64 - want).abs() < 1e-3, "{n}");
        let az = (k as f64 * GOLDEN_ANGLE_DEG).rem_euclid(360.0);
        assert!(k == 0 || (v.azimuth_deg as f64 - az).abs() < 1e-3, "{n}");
    }
    assert!((parse_view(names[9]).unwrap().angle_deg - 20.0).abs() < 1e-3);
    // Every instance gets every viewpoint; seeds differ per viewpoint.
    let plan = expand(&j);
    assert_eq!(plan.items.len(), 2 * 16);
    let seeds: std::collections::BTreeSet<u64> = plan.items.iter().map(|i| i.seed).collect();
    assert_eq!(seeds.len(), 32);
    // The job stored in a dataset folder reads back the same (views stay as given).
    let stored = toml::to_string(&j).unwrap();
    let back = Job::parse_stored(&stored, "stored").unwrap();
    assert!(back.same_except_postprocess(&j));
    assert_eq!(back.viewpoints().len(), 16);
}

#[test]
fn views_default_to_the_papers_only_without_plan_or_pose() {
    assert_eq!(job("").unwrap().viewpoints().len(), 9);
    let j = job("plan = { ring = { face = \"A\", tilt_deg = 10, count = 3, azimuth_deg = 30 } }")
        .unwrap();
    let names: Vec<String> = j
        .viewpoints()
        .iter()
        .map(|v| v.name().to_string())
        .collect();
    assert_eq!(names, ["A10@30", "A10@150", "A10@270"]);
    // The same views by name render the same viewpoint: the name is the view.
    assert_eq!(
        job("views = [\"A10@30\", \"A10@150\", \"A10@270\"]")
            .unwrap()
            .viewpoints(),
        j.viewpoints()
    );
}

#[test]
fn bad_plans_and_poses_name_the_field() {
    for (text, want) in [
        (
            "plan = { cone = { face = \"D\", max_tilt_deg = 20, count = 9 } }",
            "plan.cone.face",
        ),
        (
            "plan = { cone = { face = \"A\", max_tilt_deg = 95, count = 9 } }",
            "plan.cone.max_tilt_deg",
        ),
        (
            "plan = { ring = { face = \"A\", tilt_deg = 10, count = 0 } }",
            "plan.ring.count",
        ),
        ("plan = {}", "plan"),
        ("views = [\"A10@400\"]", "views[0]"),
        (
            "views = [\"A10\"]\nplan = { ring = { face = \"A\", tilt_deg = 10, count = 1 } }",
            "every viewpoint name once",
        ),
        ("[[pose]]\nname = \"p\"", "pose[0]"),
        (
            "[[pose]]\nname = \"A20\"\nlook_at = { eye = [0, 0, 9], target = [0, 0, 0], up = [0, 1, 0] }",
            "pose[0].name",
        ),
        (
            "[[pose]]\nname = \"p\"\nlook_at = { eye = [0, 0, 9], target = [0, 0, 0] }",
            "parallel",
        ),
        (
            "[[pose]]\nname = \"p\"\nlook_at = { eye = [0, 0, 9], target = [0, 0, 0], up = [0, 1, 0] }\nopencv = { rvec = [0, 0, 0], tvec = [0, 0, 1] }",
            "look_at and opencv",
        ),
    ] {
        let e = job(text).unwrap_err();
        assert!(e.contains(want), "{text}: {e}");
    }
}
