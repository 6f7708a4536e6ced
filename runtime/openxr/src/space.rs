//! Spaces and poses. There is no tracker: the head holds still at the
//! origin of LOCAL (a [`PoseSource`] is where a tracker would plug in), the
//! STAGE's floor is below it, and action spaces are never located.

use glam::{Quat, Vec3};
use openxr_sys as xr;

use crate::ffi::XrResult;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    pub orientation: Quat,
    pub position: Vec3,
}

impl Pose {
    pub const IDENTITY: Self = Self {
        orientation: Quat::IDENTITY,
        position: Vec3::ZERO,
    };

    pub fn at(position: Vec3) -> Self {
        Self {
            orientation: Quat::IDENTITY,
            position,
        }
    }

    /// An application's pose: its orientation must be a unit quaternion
    /// (§2.17: within 1 % after normalisation) and every number finite,
    /// else `XR_ERROR_POSE_INVALID`.
    pub fn from_xr(p: &xr::Posef) -> XrResult<Self> {
        let q = Quat::from_xyzw(
            p.orientation.x,
            p.orientation.y,
            p.orientation.z,
            p.orientation.w,
        );
        let v = Vec3::new(p.position.x, p.position.y, p.position.z);
        if !(q.is_finite() && v.is_finite() && (q.length() - 1.0).abs() < 0.01) {
            return Err(xr::Result::ERROR_POSE_INVALID);
        }
        Ok(Self {
            orientation: q.normalize(),
            position: v,
        })
    }

    pub fn to_xr(self) -> xr::Posef {
        let q = self.orientation;
        let p = self.position;
        xr::Posef {
            orientation: xr::Quaternionf {
                x: q.x,
                y: q.y,
                z: q.z,
                w: q.w,
            },
            position: xr::Vector3f {
                x: p.x,
                y: p.y,
                z: p.z,
            },
        }
    }

    /// `self ∘ child`: a pose given in this pose's frame, in its parent's.
    pub fn then(self, child: Self) -> Self {
        Self {
            orientation: self.orientation * child.orientation,
            position: self.position + self.orientation * child.position,
        }
    }

    pub fn inverse(self) -> Self {
        let inv = self.orientation.inverse();
        Self {
            orientation: inv,
            position: -(inv * self.position),
        }
    }

    /// A point given in this pose's frame, in its parent's.
    pub fn apply(self, p: Vec3) -> Vec3 {
        self.position + self.orientation * p
    }
}

/// Where the head and eyes are: a tracker's job. Poses are in LOCAL.
pub trait PoseSource: Send + Sync + std::fmt::Debug {
    /// The head (VIEW space's origin) at `time_ns`.
    fn head(&self, time_ns: i64) -> Pose;
    /// Each eye in the head's frame (left, right).
    fn eyes(&self) -> [Pose; 2];
    /// The STAGE's origin: on the floor below where the head started.
    fn stage(&self) -> Pose;
}

/// The head at LOCAL's origin, not moving; eyes `ipd_m` apart; the floor
/// `eye_height_m` below.
#[derive(Debug, Clone, Copy)]
pub struct FixedHead {
    pub ipd_m: f32,
    pub eye_height_m: f32,
}

impl Default for FixedHead {
    /// The adult median interpupillary distance (63 mm) and a standing
    /// eye height of 1.6 m.
    fn default() -> Self {
        Self {
            ipd_m: 0.063,
            eye_height_m: 1.6,
        }
    }
}

impl PoseSource for FixedHead {
    fn head(&self, _time_ns: i64) -> Pose {
        Pose::IDENTITY
    }

    fn eyes(&self) -> [Pose; 2] {
        let h = self.ipd_m / 2.0;
        [
            Pose::at(Vec3::new(-h, 0.0, 0.0)),
            Pose::at(Vec3::new(h, 0.0, 0.0)),
        ]
    }

    fn stage(&self) -> Pose {
        Pose::at(Vec3::new(0.0, -self.eye_height_m, 0.0))
    }
}

/// What a space is attached to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SpaceKind {
    Reference(xr::ReferenceSpaceType),
    /// An action's pose: with no controllers, never located.
    Action {
        action: u64,
        subaction: u64,
    },
}

/// The reference spaces this runtime offers.
pub const REFERENCE_SPACES: [xr::ReferenceSpaceType; 3] = [
    xr::ReferenceSpaceType::VIEW,
    xr::ReferenceSpaceType::LOCAL,
    xr::ReferenceSpaceType::STAGE,
];

/// A space's origin in LOCAL at `time_ns` (its offset pose included), or
/// `None` where it cannot be located.
pub fn in_local(
    source: &dyn PoseSource,
    kind: SpaceKind,
    offset: Pose,
    time_ns: i64,
) -> Option<Pose> {
    let origin = match kind {
        SpaceKind::Reference(xr::ReferenceSpaceType::VIEW) => source.head(time_ns),
        SpaceKind::Reference(xr::ReferenceSpaceType::LOCAL) => Pose::IDENTITY,
        SpaceKind::Reference(xr::ReferenceSpaceType::STAGE) => source.stage(),
        SpaceKind::Reference(_) | SpaceKind::Action { .. } => return None,
    };
    Some(origin.then(offset))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn poses_compose_and_invert() {
        let a = Pose {
            orientation: Quat::from_rotation_y(0.7),
            position: Vec3::new(1.0, 2.0, 3.0),
        };
        let b = Pose {
            orientation: Quat::from_rotation_x(-0.3),
            position: Vec3::new(-0.5, 0.0, 0.25),
        };
        let id = a.then(b).then(b.inverse()).then(a.inverse());
        assert!(id.position.length() < 1e-5);
        assert!(id.orientation.angle_between(Quat::IDENTITY) < 1e-3);
        assert!((a.apply(Vec3::ZERO) - a.position).length() < 1e-6);
    }

    #[test]
    fn a_pose_that_is_no_rotation_is_refused() {
        let mut p = Pose::IDENTITY.to_xr();
        assert!(Pose::from_xr(&p).is_ok());
        p.orientation.w = 0.5;
        assert_eq!(Pose::from_xr(&p), Err(xr::Result::ERROR_POSE_INVALID));
        p.orientation.w = f32::NAN;
        assert_eq!(Pose::from_xr(&p), Err(xr::Result::ERROR_POSE_INVALID));
    }

    #[test]
    fn the_stage_is_below_the_head_and_views_are_located_in_local() {
        let head = FixedHead::default();
        let stage = in_local(
            &head,
            SpaceKind::Reference(xr::ReferenceSpaceType::STAGE),
            Pose::IDENTITY,
            0,
        );
        assert_eq!(stage.map(|p| p.position.y), Some(-1.6));
        let action = SpaceKind::Action {
            action: 1,
            subaction: 0,
        };
        assert_eq!(in_local(&head, action, Pose::IDENTITY, 0), None);
        let [l, r] = head.eyes();
        assert!((r.position.x - l.position.x - 0.063).abs() < 1e-7);
    }
}
