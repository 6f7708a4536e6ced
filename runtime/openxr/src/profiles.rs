//! The interaction profiles of OpenXR 1.0 (§6.4) and their input and
//! output paths, from the specification's registry (`xr.xml`'s
//! `<interaction_profile>` elements). No device here fills them; the table
//! only lets `xrSuggestInteractionProfileBindings` tell a binding the
//! specification defines from one it does not (`XR_ERROR_PATH_UNSUPPORTED`).

/// One interaction profile: its top-level user paths, and its components,
/// each on every user path or on one only.
pub struct Profile {
    pub path: &'static str,
    pub user_paths: &'static [&'static str],
    pub components: &'static [(Option<&'static str>, &'static str)],
}

/// The top-level user paths an action's subaction path may name (§6.3.1).
pub const TOP_LEVEL_USER_PATHS: &[&str] = &[
    "/user/hand/left",
    "/user/hand/right",
    "/user/head",
    "/user/gamepad",
    "/user/treadmill",
];

/// The profile of this path, if OpenXR 1.0 defines it.
pub fn profile(path: &str) -> Option<&'static Profile> {
    PROFILES.iter().find(|p| p.path == path)
}

impl Profile {
    /// Whether `binding` is one of this profile's input or output paths: a
    /// user path and a component, or a user path and an identifier whose
    /// component the runtime picks (§6.3.2: `…/input/trigger` for its
    /// value, `…/input/select` for its click).
    pub fn binds(&self, binding: &str) -> bool {
        self.user_paths.iter().any(|user| {
            let Some(rest) = binding.strip_prefix(user) else {
                return false;
            };
            self.components.iter().any(|&(only, sub)| {
                if only.is_some_and(|u| u != *user) {
                    return false;
                }
                rest == sub || identifier(sub) == Some(rest)
            })
        })
    }
}

/// `/input/trigger` of `/input/trigger/value`: a component's identifier,
/// where the component is not already one (`/input/thumbstick`).
fn identifier(sub: &str) -> Option<&str> {
    let (parent, _) = sub.rsplit_once('/')?;
    (parent.matches('/').count() == 2).then_some(parent)
}

pub const PROFILES: &[Profile] = &[
    Profile {
        path: "/interaction_profiles/khr/simple_controller",
        user_paths: &["/user/hand/left", "/user/hand/right"],
        components: &[
            (None, "/input/select/click"),
            (None, "/input/menu/click"),
            (None, "/input/grip/pose"),
            (None, "/input/aim/pose"),
            (None, "/output/haptic"),
        ],
    },
    Profile {
        path: "/interaction_profiles/google/daydream_controller",
        user_paths: &["/user/hand/left", "/user/hand/right"],
        components: &[
            (None, "/input/select/click"),
            (None, "/input/trackpad"),
            (None, "/input/trackpad/x"),
            (None, "/input/trackpad/y"),
            (None, "/input/trackpad/click"),
            (None, "/input/trackpad/touch"),
            (None, "/input/grip/pose"),
            (None, "/input/aim/pose"),
        ],
    },
    Profile {
        path: "/interaction_profiles/htc/vive_controller",
        user_paths: &["/user/hand/left", "/user/hand/right"],
        components: &[
            (None, "/input/system/click"),
            (None, "/input/squeeze/click"),
            (None, "/input/menu/click"),
            (None, "/input/trigger/click"),
            (None, "/input/trigger/value"),
            (None, "/input/trackpad"),
            (None, "/input/trackpad/x"),
            (None, "/input/trackpad/y"),
            (None, "/input/trackpad/click"),
            (None, "/input/trackpad/touch"),
            (None, "/input/grip/pose"),
            (None, "/input/aim/pose"),
            (None, "/output/haptic"),
        ],
    },
    Profile {
        path: "/interaction_profiles/htc/vive_pro",
        user_paths: &["/user/head"],
        components: &[
            (None, "/input/system/click"),
            (None, "/input/volume_up/click"),
            (None, "/input/volume_down/click"),
            (None, "/input/mute_mic/click"),
        ],
    },
    Profile {
        path: "/interaction_profiles/microsoft/motion_controller",
        user_paths: &["/user/hand/left", "/user/hand/right"],
        components: &[
            (None, "/input/menu/click"),
            (None, "/input/squeeze/click"),
            (None, "/input/trigger/value"),
            (None, "/input/thumbstick"),
            (None, "/input/thumbstick/x"),
            (None, "/input/thumbstick/y"),
            (None, "/input/thumbstick/click"),
            (None, "/input/trackpad"),
            (None, "/input/trackpad/x"),
            (None, "/input/trackpad/y"),
            (None, "/input/trackpad/click"),
            (None, "/input/trackpad/touch"),
            (None, "/input/grip/pose"),
            (None, "/input/aim/pose"),
            (None, "/output/haptic"),
        ],
    },
    Profile {
        path: "/interaction_profiles/microsoft/xbox_controller",
        user_paths: &["/user/gamepad"],
        components: &[
            (None, "/input/menu/click"),
            (None, "/input/view/click"),
            (None, "/input/a/click"),
            (None, "/input/b/click"),
            (None, "/input/x/click"),
            (None, "/input/y/click"),
            (None, "/input/dpad_down/click"),
            (None, "/input/dpad_right/click"),
            (None, "/input/dpad_up/click"),
            (None, "/input/dpad_left/click"),
            (None, "/input/shoulder_left/click"),
            (None, "/input/shoulder_right/click"),
            (None, "/input/thumbstick_left/click"),
            (None, "/input/thumbstick_right/click"),
            (None, "/input/trigger_left/value"),
            (None, "/input/trigger_right/value"),
            (None, "/input/thumbstick_left"),
            (None, "/input/thumbstick_left/x"),
            (None, "/input/thumbstick_left/y"),
            (None, "/input/thumbstick_right"),
            (None, "/input/thumbstick_right/x"),
            (None, "/input/thumbstick_right/y"),
            (None, "/output/haptic_left"),
            (None, "/output/haptic_right"),
            (None, "/output/haptic_left_trigger"),
            (None, "/output/haptic_right_trigger"),
        ],
    },
    Profile {
        path: "/interaction_profiles/oculus/go_controller",
        user_paths: &["/user/hand/left", "/user/hand/right"],
        components: &[
            (None, "/input/system/click"),
            (None, "/input/trigger/click"),
            (None, "/input/back/click"),
            (None, "/input/trackpad"),
            (None, "/input/trackpad/x"),
            (None, "/input/trackpad/y"),
            (None, "/input/trackpad/click"),
            (None, "/input/trackpad/touch"),
            (None, "/input/grip/pose"),
            (None, "/input/aim/pose"),
        ],
    },
    Profile {
        path: "/interaction_profiles/oculus/touch_controller",
        user_paths: &["/user/hand/left", "/user/hand/right"],
        components: &[
            (Some("/user/hand/left"), "/input/x/click"),
            (Some("/user/hand/left"), "/input/x/touch"),
            (Some("/user/hand/left"), "/input/y/click"),
            (Some("/user/hand/left"), "/input/y/touch"),
            (Some("/user/hand/left"), "/input/menu/click"),
            (Some("/user/hand/right"), "/input/a/click"),
            (Some("/user/hand/right"), "/input/a/touch"),
            (Some("/user/hand/right"), "/input/b/click"),
            (Some("/user/hand/right"), "/input/b/touch"),
            (Some("/user/hand/right"), "/input/system/click"),
            (None, "/input/squeeze/value"),
            (None, "/input/trigger/value"),
            (None, "/input/trigger/touch"),
            (None, "/input/thumbstick"),
            (None, "/input/thumbstick/x"),
            (None, "/input/thumbstick/y"),
            (None, "/input/thumbstick/click"),
            (None, "/input/thumbstick/touch"),
            (None, "/input/thumbrest/touch"),
            (None, "/input/grip/pose"),
            (None, "/input/aim/pose"),
            (None, "/output/haptic"),
        ],
    },
    Profile {
        path: "/interaction_profiles/valve/index_controller",
        user_paths: &["/user/hand/left", "/user/hand/right"],
        components: &[
            (None, "/input/system/click"),
            (None, "/input/system/touch"),
            (None, "/input/a/click"),
            (None, "/input/a/touch"),
            (None, "/input/b/click"),
            (None, "/input/b/touch"),
            (None, "/input/squeeze/value"),
            (None, "/input/squeeze/force"),
            (None, "/input/trigger/click"),
            (None, "/input/trigger/value"),
            (None, "/input/trigger/touch"),
            (None, "/input/thumbstick"),
            (None, "/input/thumbstick/x"),
            (None, "/input/thumbstick/y"),
            (None, "/input/thumbstick/click"),
            (None, "/input/thumbstick/touch"),
            (None, "/input/trackpad"),
            (None, "/input/trackpad/x"),
            (None, "/input/trackpad/y"),
            (None, "/input/trackpad/force"),
            (None, "/input/trackpad/touch"),
            (None, "/input/grip/pose"),
            (None, "/input/aim/pose"),
            (None, "/output/haptic"),
        ],
    },
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bindings_are_the_profiles_own() {
        let simple = profile("/interaction_profiles/khr/simple_controller").expect("simple");
        assert!(simple.binds("/user/hand/left/input/select/click"));
        assert!(simple.binds("/user/hand/left/input/select"));
        assert!(simple.binds("/user/hand/right/output/haptic"));
        // The CTS's unknown binding paths (xrSuggestInteractionProfileBindings).
        for bad in [
            "/invalid",
            "/user/invalid",
            "/user/hand/invalid",
            "/user/hand/right",
            "/user/hand/right/invalid",
            "/user/hand/right/input",
            "/user/hand/invalid/input",
            "/user/invalid/right/input",
            "/invalid/hand/right/input",
            "/user/hand/left/input_bad/menu/click",
            "/user/hand/right/input/select/click/invalid",
        ] {
            assert!(!simple.binds(bad), "{bad}");
        }
        let touch = profile("/interaction_profiles/oculus/touch_controller").expect("touch");
        assert!(touch.binds("/user/hand/left/input/x/click"));
        assert!(!touch.binds("/user/hand/right/input/x/click"));
        assert!(touch.binds("/user/hand/right/input/thumbstick"));
        assert!(touch.binds("/user/hand/right/input/thumbstick/x"));
        assert!(profile("/interaction_profiles/khr/another_controller").is_none());
        assert!(profile("/interaction_profiles/khr/simple_controller/invalid").is_none());
    }

    #[test]
    fn every_profile_has_users_and_well_formed_components() {
        assert_eq!(PROFILES.len(), 9);
        for p in PROFILES {
            assert!(crate::instance::valid_path(p.path), "{}", p.path);
            assert!(!p.user_paths.is_empty());
            for &(only, sub) in p.components {
                assert!(only.is_none_or(|u| p.user_paths.contains(&u)), "{sub}");
                let full = format!("{}{sub}", p.user_paths[0]);
                assert!(crate::instance::valid_path(&full), "{full}");
            }
        }
    }
}
