//! The space entry points (§7): reference spaces, action spaces, and
//! locating one in another.

use std::sync::Arc;

use openxr_sys as xr;
use openxr_sys::Handle as _;

use crate::ffi::{XrResult, expect_type, guard, lock, non_null, non_null_mut, two_call};
use crate::space::{Pose, REFERENCE_SPACES, SpaceKind, in_local};
use crate::state::{Session, Space, registry};

pub unsafe extern "system" fn enumerate_reference_spaces(
    session: xr::Session,
    capacity: u32,
    count: *mut u32,
    spaces: *mut xr::ReferenceSpaceType,
) -> xr::Result {
    guard("xrEnumerateReferenceSpaces", || {
        registry().session(session)?;
        // SAFETY: the application's arrays.
        unsafe { two_call(capacity, count, spaces, &REFERENCE_SPACES) }
    })
}

fn add_space(
    session: &Session,
    kind: SpaceKind,
    pose: Pose,
    out: *mut xr::Space,
) -> XrResult<xr::Result> {
    let out = non_null_mut(out)?;
    let mut reg = registry();
    let h = reg.new_handle();
    reg.spaces.insert(
        h,
        Arc::new(Space {
            session: session.handle,
            kind,
            pose_in_parent: pose,
        }),
    );
    // SAFETY: non-null output.
    unsafe { out.write(xr::Space::from_raw(h)) };
    Ok(xr::Result::SUCCESS)
}

pub unsafe extern "system" fn create_reference_space(
    session: xr::Session,
    info: *const xr::ReferenceSpaceCreateInfo,
    out: *mut xr::Space,
) -> xr::Result {
    guard("xrCreateReferenceSpace", || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::REFERENCE_SPACE_CREATE_INFO)?;
        let s = registry().session(session)?;
        if !REFERENCE_SPACES.contains(&info.reference_space_type) {
            return Err(xr::Result::ERROR_REFERENCE_SPACE_UNSUPPORTED);
        }
        let pose = Pose::from_xr(&info.pose_in_reference_space)?;
        add_space(
            &s,
            SpaceKind::Reference(info.reference_space_type),
            pose,
            out,
        )
    })
}

pub unsafe extern "system" fn create_action_space(
    session: xr::Session,
    info: *const xr::ActionSpaceCreateInfo,
    out: *mut xr::Space,
) -> xr::Result {
    guard("xrCreateActionSpace", || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::ACTION_SPACE_CREATE_INFO)?;
        let (s, action) = {
            let reg = registry();
            (reg.session(session)?, reg.action(info.action)?)
        };
        if action.action_type != xr::ActionType::POSE_INPUT {
            return Err(xr::Result::ERROR_ACTION_TYPE_MISMATCH);
        }
        let sub = info.subaction_path.into_raw();
        if sub != 0 && !action.subaction_paths.contains(&sub) {
            return Err(xr::Result::ERROR_PATH_UNSUPPORTED);
        }
        let pose = Pose::from_xr(&info.pose_in_action_space)?;
        let kind = SpaceKind::Action {
            action: info.action.into_raw(),
            subaction: sub,
        };
        add_space(&s, kind, pose, out)
    })
}

pub unsafe extern "system" fn destroy_space(space: xr::Space) -> xr::Result {
    guard("xrDestroySpace", || {
        registry()
            .spaces
            .remove(&space.into_raw())
            .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
        Ok(xr::Result::SUCCESS)
    })
}

/// A space's origin in LOCAL, if it can be located.
pub fn locate_in_local(session: &Session, space: &Space, time: i64) -> Option<Pose> {
    let poses = lock(&session.inner).poses.clone();
    in_local(poses.as_ref(), space.kind, space.pose_in_parent, time)
}

pub unsafe extern "system" fn locate_space(
    space: xr::Space,
    base: xr::Space,
    time: xr::Time,
    location: *mut xr::SpaceLocation,
) -> xr::Result {
    guard("xrLocateSpace", || {
        let location = non_null_mut(location)?;
        let (sp, bs, s) = {
            let reg = registry();
            let sp = reg.space(space)?;
            let bs = reg.space(base)?;
            let s = reg
                .sessions
                .get(&sp.session)
                .cloned()
                .ok_or(xr::Result::ERROR_HANDLE_INVALID)?;
            (sp, bs, s)
        };
        if time.as_nanos() <= 0 {
            return Err(xr::Result::ERROR_TIME_INVALID);
        }
        // SAFETY: non-null; the application initialised its type.
        let location = unsafe { &mut *location };
        expect_type(location.ty, xr::StructureType::SPACE_LOCATION)?;
        (location.location_flags, location.pose) = locate(&s, &sp, &bs, time.as_nanos());
        Ok(xr::Result::SUCCESS)
    })
}

/// `space` in `base` at `t`: valid, never tracked (no tracker measures the
/// head), or nothing where either cannot be located.
fn locate(s: &Session, space: &Space, base: &Space, t: i64) -> (xr::SpaceLocationFlags, xr::Posef) {
    match (locate_in_local(s, space, t), locate_in_local(s, base, t)) {
        (Some(p), Some(b)) => (
            xr::SpaceLocationFlags::ORIENTATION_VALID | xr::SpaceLocationFlags::POSITION_VALID,
            b.inverse().then(p).to_xr(),
        ),
        _ => (xr::SpaceLocationFlags::EMPTY, Pose::IDENTITY.to_xr()),
    }
}

/// xrLocateSpaces (core in OpenXR 1.1): xrLocateSpace for several spaces at
/// once. The CTS's xrGetInstanceProcAddr case expects it resolved also
/// on a 1.0 instance, as its function table lists it with no extension.
pub unsafe extern "system" fn locate_spaces(
    session: xr::Session,
    info: *const xr::SpacesLocateInfo,
    locations: *mut xr::SpaceLocations,
) -> xr::Result {
    guard("xrLocateSpaces", || {
        let info = non_null(info)?;
        let locations = non_null_mut(locations)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::SPACES_LOCATE_INFO)?;
        // SAFETY: non-null; the application initialised its type.
        let locations = unsafe { &mut *locations };
        expect_type(locations.ty, xr::StructureType::SPACE_LOCATIONS)?;
        if info.space_count == 0 || info.space_count != locations.location_count {
            return Err(xr::Result::ERROR_VALIDATION_FAILURE);
        }
        let spaces = non_null(info.spaces)?;
        let out = non_null_mut(locations.locations)?;
        let (s, base, located) = {
            let reg = registry();
            let s = reg.session(session)?;
            let base = reg.space(info.base_space)?;
            let mut located = Vec::with_capacity(info.space_count as usize);
            for i in 0..info.space_count as usize {
                // SAFETY: space_count handles (the application).
                located.push(reg.space(unsafe { *spaces.add(i) })?);
            }
            (s, base, located)
        };
        if base.session != s.handle || located.iter().any(|sp| sp.session != s.handle) {
            return Err(xr::Result::ERROR_VALIDATION_FAILURE);
        }
        if info.time.as_nanos() <= 0 {
            return Err(xr::Result::ERROR_TIME_INVALID);
        }
        for (i, sp) in located.iter().enumerate() {
            let (location_flags, pose) = locate(&s, sp, &base, info.time.as_nanos());
            // SAFETY: location_count (= space_count) elements.
            unsafe {
                out.add(i).write(xr::SpaceLocationData {
                    location_flags,
                    pose,
                })
            };
        }
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn get_reference_space_bounds_rect(
    session: xr::Session,
    kind: xr::ReferenceSpaceType,
    bounds: *mut xr::Extent2Df,
) -> xr::Result {
    guard("xrGetReferenceSpaceBoundsRect", || {
        let bounds = non_null_mut(bounds)?;
        registry().session(session)?;
        if !REFERENCE_SPACES.contains(&kind) {
            return Err(xr::Result::ERROR_REFERENCE_SPACE_UNSUPPORTED);
        }
        // SAFETY: non-null output.
        unsafe {
            bounds.write(xr::Extent2Df {
                width: 0.0,
                height: 0.0,
            })
        };
        Ok(xr::Result::SPACE_BOUNDS_UNAVAILABLE)
    })
}
