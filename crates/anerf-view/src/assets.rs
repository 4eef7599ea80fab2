//! The viewer's page, scripts and style, compiled into the binary so that `anerf view` needs no network
//! and no file beside the executable.

const ASSETS: &[(&str, &[u8])] = &[
    ("index.html", include_bytes!("assets/index.html")),
    ("app.js", include_bytes!("assets/app.js")),
    ("glb_view.js", include_bytes!("assets/glb_view.js")),
    ("splat_view.js", include_bytes!("assets/splat_view.js")),
    ("view3d.js", include_bytes!("assets/view3d.js")),
    ("style.css", include_bytes!("assets/style.css")),
];

/// The asset called `name`, if there is one.
pub fn get(name: &str) -> Option<&'static [u8]> {
    ASSETS.iter().find(|(n, _)| *n == name).map(|(_, b)| *b)
}
