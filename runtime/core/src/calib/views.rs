//! The headset's views (issue 33): where each eye's image lies on the
//! panel and which design its eyepiece is (two fabricated DOEs are never
//! identical). `[[view]]` tables in the calibration; none: one view, the
//! whole panel (`nedrt run --stereo` then splits the panel in halves, both
//! eyes the shipped design).

use serde::{Deserialize, Serialize};

use super::CalibError;

/// A `[[view]]` table as written.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawView {
    pub name: String,
    /// x, y, width, height on the panel, pixels.
    pub region_px: [usize; 4],
    /// A design name or file (`designs/`); none: the run's own.
    #[serde(default)]
    pub design: Option<String>,
}

/// A validated view.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct ViewSettings {
    pub name: String,
    pub region_px: [usize; 4],
    pub design: Option<String>,
}

/// The most views: a headset's two eyes.
pub const MAX_VIEWS: usize = 2;

/// The smallest side of a view, pixels (as an image `sim` takes).
pub const MIN_VIEW_SIDE_PX: usize = 8;

/// Checks `raw` against a `width`×`height` panel: at most two views, each
/// named once, at least 8 pixels a side, inside the panel, not overlapping.
pub fn resolve(
    raw: &[RawView],
    (width, height): (usize, usize),
    path: &str,
) -> Result<Vec<ViewSettings>, CalibError> {
    let bad = |field: String, reason: String| CalibError::Invalid {
        path: path.to_string(),
        field,
        reason,
    };
    if raw.len() > MAX_VIEWS {
        return Err(bad(
            "view".into(),
            format!(
                "{} views; a headset has at most {MAX_VIEWS} (its eyes)",
                raw.len()
            ),
        ));
    }
    let mut views: Vec<ViewSettings> = Vec::new();
    for (i, v) in raw.iter().enumerate() {
        let field = format!("view[{i}]");
        let [x, y, w, h] = v.region_px;
        if v.name.trim().is_empty() || views.iter().any(|o| o.name == v.name) {
            return Err(bad(
                format!("{field}.name"),
                format!("{:?}: each view needs a name of its own", v.name),
            ));
        }
        if w < MIN_VIEW_SIDE_PX || h < MIN_VIEW_SIDE_PX {
            return Err(bad(
                format!("{field}.region_px"),
                format!("{w}×{h} pixels; a view is at least {MIN_VIEW_SIDE_PX} a side"),
            ));
        }
        let inside = x.checked_add(w).is_some_and(|r| r <= width)
            && y.checked_add(h).is_some_and(|b| b <= height);
        if !inside {
            return Err(bad(
                format!("{field}.region_px"),
                format!("{w}×{h} at ({x}, {y}) is not inside the {width}×{height} panel"),
            ));
        }
        if let Some(o) = views.iter().find(|o| {
            let [ox, oy, ow, oh] = o.region_px;
            x < ox + ow && ox < x + w && y < oy + oh && oy < y + h
        }) {
            return Err(bad(
                format!("{field}.region_px"),
                format!("overlaps view {:?}", o.name),
            ));
        }
        if v.design.as_deref().is_some_and(|d| d.trim().is_empty()) {
            return Err(bad(format!("{field}.design"), "empty".into()));
        }
        views.push(ViewSettings {
            name: v.name.clone(),
            region_px: v.region_px,
            design: v.design.clone(),
        });
    }
    Ok(views)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(name: &str, region_px: [usize; 4]) -> RawView {
        RawView {
            name: name.into(),
            region_px,
            design: None,
        }
    }

    #[test]
    fn two_eyes_side_by_side_pass_and_bad_regions_are_named() {
        let panel = (128, 48);
        let ok = resolve(
            &[view("left", [0, 0, 64, 48]), view("right", [64, 0, 64, 48])],
            panel,
            "c.toml",
        )
        .expect("valid");
        assert_eq!(ok.len(), 2);
        let e = |views: &[RawView]| {
            resolve(views, panel, "c.toml")
                .expect_err("bad")
                .to_string()
        };
        assert!(
            e(&[view("left", [0, 0, 64, 48]), view("left", [64, 0, 64, 48])])
                .contains("view[1].name")
        );
        assert!(e(&[view("left", [70, 0, 64, 48])]).contains("not inside the 128×48 panel"));
        assert!(e(&[view("left", [0, 0, 4, 48])]).contains("at least 8 a side"));
        assert!(
            e(&[view("left", [0, 0, 70, 48]), view("right", [64, 0, 64, 48])])
                .contains("overlaps view \"left\"")
        );
        assert!(
            e(&[
                view("a", [0, 0, 8, 8]),
                view("b", [8, 0, 8, 8]),
                view("c", [16, 0, 8, 8])
            ])
            .contains("at most 2")
        );
        assert!(e(&[view("left", [usize::MAX, 0, 64, 48])]).contains("not inside"));
    }
}
