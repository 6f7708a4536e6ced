//! The frame loop (§10.4): `xrWaitFrame` paces the application on the
//! service's refresh, `xrEndFrame` sends its layers to the service.

use nedrt_protocol::{PixelFormat, Placement};
use openxr_sys as xr;

use crate::ffi::{XrResult, expect_type, guard, lock, non_null, non_null_mut, now_ns};
use crate::link::{LinkError, SystemInfo, Timing};
use crate::pixels::{self, QuadAlpha};
use crate::session::session_and_instance;
use crate::space::Pose;
use crate::state::{SessionInner, registry};
use crate::swapchain::{check_sub_image, read_released};

/// The most layers a frame may have (XrSystemGraphicsProperties).
pub const MAX_LAYERS: u32 = 16;

/// The refresh a frame started now is shown at, and when to start it.
///
/// The service's replies give its lead (`lead_ns`) from a submission to
/// the refresh it is shown at. A frame started now is submitted `make_ns`
/// later (the application's rendering and the copy-out, as learnt), so it
/// is given the first refresh on the service's grid (`timing`) at or after
/// now + `make_ns` + the lead, and never the same refresh twice; it should
/// start the lead and `make_ns` before that refresh.
pub fn next_frame(
    timing: Timing,
    lead_ns: i64,
    now: i64,
    last_predicted: i64,
    make_ns: i64,
) -> (i64, i64) {
    let period = timing.period_ns.max(1);
    let ahead = lead_ns.max(0) + make_ns.max(0);
    let behind = (now + ahead - timing.predicted_display_ns).max(0);
    let steps = (behind + period - 1) / period;
    let mut predicted = timing.predicted_display_ns + steps * period;
    if predicted <= last_predicted {
        let behind = (last_predicted - predicted) / period + 1;
        predicted += behind * period;
    }
    (predicted, predicted - ahead)
}

fn sleep_until(t: i64) {
    let now = now_ns();
    if t > now {
        std::thread::sleep(std::time::Duration::from_nanos((t - now) as u64));
    }
}

pub unsafe extern "system" fn wait_frame(
    session: xr::Session,
    info: *const xr::FrameWaitInfo,
    state: *mut xr::FrameState,
) -> xr::Result {
    guard("xrWaitFrame", || {
        let state = non_null_mut(state)?;
        if !info.is_null() {
            // SAFETY: non-null, from the application.
            let ty = unsafe { (*info).ty };
            expect_type(ty, xr::StructureType::FRAME_WAIT_INFO)?;
        }
        // SAFETY: non-null; the application initialised its type.
        let state = unsafe { &mut *state };
        expect_type(state.ty, xr::StructureType::FRAME_STATE)?;
        let (s, inst) = session_and_instance(session)?;
        // One waiter at a time; the session itself stays unlocked while
        // this one sleeps, so other threads' calls go on.
        let _one = lock(&s.wait_lock);
        let (predicted, wake, period) = {
            let mut inner = lock(&s.inner);
            if let Some(link) = inner.link.as_mut()
                && let Err(e) = link.alive()
            {
                inner.lose(&inst, s.handle, &e);
            }
            if inner.lost {
                // The service is gone: the application is told the session
                // is ending (a success code, §9.3) and paced on the last
                // known refresh until it destroys the session.
                let period = inner.info.refresh_period_ns.max(1) as i64;
                let predicted = inner.frame.last_predicted.max(now_ns()) + period;
                inner.frame.last_predicted = predicted;
                drop(inner);
                sleep_until(predicted - period);
                state.predicted_display_time = xr::Time::from_nanos(predicted);
                state.predicted_display_period = xr::Duration::from_nanos(period);
                state.should_render = xr::FALSE;
                return Ok(xr::Result::SESSION_LOSS_PENDING);
            }
            inner.check_running()?;
            let (timing, lead) = inner
                .link
                .as_ref()
                .and_then(|l| Some((l.timing()?, l.lead_ns()?)))
                .ok_or(xr::Result::ERROR_SESSION_LOST)?;
            let (p, w) = next_frame(
                timing,
                lead,
                now_ns(),
                inner.frame.last_predicted,
                inner.frame.make.bound_ns(),
            );
            inner.frame.last_predicted = p;
            (p, w, timing.period_ns)
        };
        sleep_until(wake);
        let mut inner = lock(&s.inner);
        inner.check_running()?;
        inner.frame.waited += 1;
        inner.frame.woke(predicted, now_ns());
        inner.advance(&inst, s.handle);
        state.predicted_display_time = xr::Time::from_nanos(predicted);
        state.predicted_display_period = xr::Duration::from_nanos(period);
        state.should_render = matches!(
            inner.state,
            xr::SessionState::VISIBLE | xr::SessionState::FOCUSED
        )
        .into();
        Ok(xr::Result::SUCCESS)
    })
}

pub unsafe extern "system" fn begin_frame(
    session: xr::Session,
    info: *const xr::FrameBeginInfo,
) -> xr::Result {
    guard("xrBeginFrame", || {
        if !info.is_null() {
            // SAFETY: non-null, from the application.
            let ty = unsafe { (*info).ty };
            expect_type(ty, xr::StructureType::FRAME_BEGIN_INFO)?;
        }
        let (s, _) = session_and_instance(session)?;
        let mut inner = lock(&s.inner);
        if inner.lost {
            return Ok(xr::Result::SESSION_LOSS_PENDING);
        }
        inner.check_running()?;
        if inner.frame.waited == 0 {
            return Err(xr::Result::ERROR_CALL_ORDER_INVALID);
        }
        inner.frame.waited -= 1;
        inner.frame.begun_ns = now_ns();
        if inner.frame.begun {
            // The previous frame began and never ended: it is discarded.
            return Ok(xr::Result::FRAME_DISCARDED);
        }
        inner.frame.begun = true;
        Ok(xr::Result::SUCCESS)
    })
}

/// A layer of the frame, checked and read.
enum Submitted {
    Projection(
        Vec<(
            xr::SwapchainSubImage,
            std::sync::Arc<crate::state::Swapchain>,
        )>,
    ),
    Quad {
        layer: xr::CompositionLayerQuad,
        sc: std::sync::Arc<crate::state::Swapchain>,
    },
}

/// §10.5's checks of one layer.
///
/// # Safety
/// `layer` must point at a layer structure of the type it names.
unsafe fn check_layer(
    layer: *const xr::CompositionLayerBaseHeader,
    views: usize,
) -> XrResult<Submitted> {
    let layer = non_null(layer).map_err(|_| xr::Result::ERROR_LAYER_INVALID)?;
    // SAFETY: non-null, from the application.
    let base = unsafe { &*layer };
    registry().space(base.space)?;
    match base.ty {
        xr::StructureType::COMPOSITION_LAYER_PROJECTION => {
            // SAFETY: the type names the structure.
            let p = unsafe { &*layer.cast::<xr::CompositionLayerProjection>() };
            if p.view_count as usize != views || p.views.is_null() {
                return Err(xr::Result::ERROR_VALIDATION_FAILURE);
            }
            let mut out = Vec::new();
            for v in 0..views {
                // SAFETY: view_count elements (checked above).
                let pv = unsafe { &*p.views.add(v) };
                expect_type(pv.ty, xr::StructureType::COMPOSITION_LAYER_PROJECTION_VIEW)?;
                // The view's pose is not used (a fixed head), but a
                // non-unit orientation is still refused (§10.5.1).
                Pose::from_xr(&pv.pose)?;
                out.push((pv.sub_image, check_sub_image(&pv.sub_image)?));
            }
            Ok(Submitted::Projection(out))
        }
        xr::StructureType::COMPOSITION_LAYER_QUAD => {
            // SAFETY: the type names the structure.
            let q = unsafe { *layer.cast::<xr::CompositionLayerQuad>() };
            Pose::from_xr(&q.pose)?;
            // A quad of zero size is valid and shows nothing (the CTS
            // submits one); a negative or non-finite size is no size.
            if !(q.size.width >= 0.0 && q.size.height >= 0.0) {
                return Err(xr::Result::ERROR_VALIDATION_FAILURE);
            }
            let sc = check_sub_image(&q.sub_image)?;
            Ok(Submitted::Quad { layer: q, sc })
        }
        _ => Err(xr::Result::ERROR_LAYER_INVALID),
    }
}

pub unsafe extern "system" fn end_frame(
    session: xr::Session,
    info: *const xr::FrameEndInfo,
) -> xr::Result {
    guard("xrEndFrame", || {
        let info = non_null(info)?;
        // SAFETY: non-null, from the application.
        let info = unsafe { &*info };
        expect_type(info.ty, xr::StructureType::FRAME_END_INFO)?;
        let (s, inst) = session_and_instance(session)?;
        let views = {
            let inner = lock(&s.inner);
            if inner.lost {
                return Ok(xr::Result::SESSION_LOSS_PENDING);
            }
            inner.check_running()?;
            if !inner.frame.begun {
                return Err(xr::Result::ERROR_CALL_ORDER_INVALID);
            }
            inner.info.views.len()
        };
        if info.display_time.as_nanos() <= 0 {
            return Err(xr::Result::ERROR_TIME_INVALID);
        }
        if info.environment_blend_mode != xr::EnvironmentBlendMode::OPAQUE {
            return Err(xr::Result::ERROR_ENVIRONMENT_BLEND_MODE_UNSUPPORTED);
        }
        if info.layer_count > MAX_LAYERS {
            return Err(xr::Result::ERROR_LAYER_LIMIT_EXCEEDED);
        }
        if info.layer_count > 0 && info.layers.is_null() {
            return Err(xr::Result::ERROR_LAYER_INVALID);
        }
        let mut layers = Vec::new();
        for i in 0..info.layer_count as usize {
            // SAFETY: layer_count pointers (checked non-null above).
            let l = unsafe { *info.layers.add(i) };
            // SAFETY: the application's layer, of the type it names.
            layers.push(unsafe { check_layer(l, views) }?);
        }
        let mut inner = lock(&s.inner);
        let time = info.display_time.as_nanos();
        if let Err(e) = compose(&mut inner, &layers, time) {
            match e {
                // A refused frame stays begun: the next xrBeginFrame
                // discards it (§10.4; the CTS's layer checks this).
                Failure::Xr(r) => return Err(r),
                Failure::Link(e) => {
                    inner.frame.begun = false;
                    inner.lose(&inst, s.handle, &e);
                    return Ok(xr::Result::SESSION_LOSS_PENDING);
                }
            }
        }
        inner.frame.begun = false;
        inner.frame.frames_ended += 1;
        inner.advance(&inst, s.handle);
        Ok(xr::Result::SUCCESS)
    })
}

enum Failure {
    Xr(xr::Result),
    Link(LinkError),
}

impl From<xr::Result> for Failure {
    fn from(r: xr::Result) -> Self {
        Self::Xr(r)
    }
}

impl From<LinkError> for Failure {
    fn from(e: LinkError) -> Self {
        Self::Link(e)
    }
}

/// Reads each layer's released image and sends it to the service: each
/// view's projection, and the quads over the views they are visible to
/// (the layer's index is its id and its height).
fn compose(inner: &mut SessionInner, layers: &[Submitted], time: i64) -> Result<(), Failure> {
    let capture = u64::try_from(inner.frame.begun_ns).unwrap_or(0);
    let info = inner.info.clone();
    let mut quads_now = vec![std::collections::BTreeSet::new(); info.views.len()];
    for (index, layer) in layers.iter().enumerate() {
        match layer {
            Submitted::Projection(views) => {
                for (v, (sub, sc)) in views.iter().enumerate() {
                    let started = now_ns();
                    let (texels, size, srgb) =
                        read_released(sc, sub.image_rect, sub.image_array_index)?;
                    inner.stats.copies += 1;
                    inner.stats.copy_ns += (now_ns() - started).max(0) as u64;
                    inner.stats.texels += (size.0 * size.1) as u64;
                    let target = info.view_size(v);
                    let rgba = pixels::projection_rgba8(&texels, size, target);
                    let format = if srgb {
                        PixelFormat::Rgba8Srgb
                    } else {
                        PixelFormat::Rgba8Linear
                    };
                    let sending = now_ns();
                    let link = inner.link.as_mut().ok_or(xr::Result::ERROR_SESSION_LOST)?;
                    let display = u64::try_from(time).unwrap_or(0);
                    link.projection(v as u8, format, target, &rgba, (capture, display))?;
                    inner.stats.send_ns += (now_ns() - sending).max(0) as u64;
                    let link = inner.link.as_mut().ok_or(xr::Result::ERROR_SESSION_LOST)?;
                    if v == 0 {
                        // The reply's prediction is the service's for a
                        // frame taken now: this one.
                        let said = link.timing().map_or(time, |t| t.predicted_display_ns);
                        // The service predicts as it replies: a frame is
                        // made by then (rendered, copied out, sent, taken).
                        // A display time no wait gave (the application's
                        // own) is not a frame the estimate can time.
                        if let Some(woke) = inner.frame.woke_for(time) {
                            log_debug!(
                                "frame for {time}: made in {:.2} ms (bound {:.2}); the service says {:+.2} periods",
                                (now_ns() - woke) as f64 / 1e6,
                                inner.frame.make.bound_ns() as f64 / 1e6,
                                (said - time) as f64 / info.refresh_period_ns.max(1) as f64
                            );
                            inner.frame.make.record(now_ns() - woke);
                        }
                        let st = &mut inner.stats;
                        st.frames += 1;
                        match said.cmp(&time) {
                            std::cmp::Ordering::Equal => st.same += 1,
                            std::cmp::Ordering::Greater => st.later += 1,
                            std::cmp::Ordering::Less => st.earlier += 1,
                        }
                    }
                }
            }
            Submitted::Quad { layer, sc } => {
                let id = index as u32;
                if layer.size.width == 0.0 || layer.size.height == 0.0 {
                    // No area: shown nowhere (and removed where it was).
                    continue;
                }
                let (texels, size, srgb) = read_released(
                    sc,
                    layer.sub_image.image_rect,
                    layer.sub_image.image_array_index,
                )?;
                let alpha = QuadAlpha {
                    blend: layer
                        .layer_flags
                        .contains(xr::CompositionLayerFlags::BLEND_TEXTURE_SOURCE_ALPHA),
                    unpremultiplied: layer
                        .layer_flags
                        .contains(xr::CompositionLayerFlags::UNPREMULTIPLIED_ALPHA),
                };
                for v in visible_views(layer.eye_visibility, info.views.len()) {
                    let Some((placement, px, region)) = place_quad(inner, &info, layer, v, time)
                    else {
                        log_debug!(
                            "quad layer {id} is outside view {v} or behind the eye: not shown there"
                        );
                        continue;
                    };
                    let rgba = pixels::quad_rgba(&texels, srgb, alpha, size, region, px);
                    let link = inner.link.as_mut().ok_or(xr::Result::ERROR_SESSION_LOST)?;
                    link.quad(v as u8, id, id as i32, placement, px, &rgba)?;
                    quads_now[v].insert(id);
                }
            }
        }
    }
    let before = std::mem::take(&mut inner.quads);
    for (v, (was, now)) in before.iter().zip(&quads_now).enumerate() {
        for &id in was.difference(now) {
            let link = inner.link.as_mut().ok_or(xr::Result::ERROR_SESSION_LOST)?;
            link.remove_quad(v as u8, id)?;
        }
    }
    inner.quads = quads_now;
    Ok(())
}

fn visible_views(eye: xr::EyeVisibility, views: usize) -> Vec<usize> {
    match eye {
        xr::EyeVisibility::LEFT => vec![0],
        xr::EyeVisibility::RIGHT if views == 2 => vec![1],
        xr::EyeVisibility::RIGHT => vec![],
        _ => (0..views).collect(),
    }
}

/// Where a quad lands on view `v`: the centre of its projected corners'
/// bounding box, cut to the view, as a direction from the view's centre;
/// the panel pixels that box covers; and the part of the quad's image it
/// shows. The service draws a quad upright, texel rows along the panel's
/// rows: a quad turned away from the eye is drawn at its bounding box
/// (docs/openxr.md). A quad larger than the view (the CTS's text quads
/// span 2463 pixels of a 32-pixel view) is cut to the view here, as the
/// service takes no quad larger than a view; None where none of it is in
/// the view or it is behind the eye.
fn place_quad(
    inner: &SessionInner,
    info: &SystemInfo,
    q: &xr::CompositionLayerQuad,
    v: usize,
    time: i64,
) -> Option<(Placement, (usize, usize), pixels::Region)> {
    let space = registry().space(q.space).ok()?;
    // The session's lock is held by the caller: locate with its poses.
    let base =
        crate::space::in_local(inner.poses.as_ref(), space.kind, space.pose_in_parent, time)?;
    let eye = inner.poses.head(time).then(if info.views.len() == 2 {
        inner.poses.eyes()[v]
    } else {
        Pose::IDENTITY
    });
    let quad = base.then(Pose::from_xr(&q.pose).ok()?);
    let to_eye = eye.inverse().then(quad);
    let (hw, hh) = (q.size.width / 2.0, q.size.height / 2.0);
    let ppt = info.pixels_per_tan as f32;
    let mut xs = Vec::new();
    let mut ys = Vec::new();
    for (cx, cy) in [(-hw, -hh), (hw, -hh), (hw, hh), (-hw, hh)] {
        let p = to_eye.apply(glam::Vec3::new(cx, cy, 0.0));
        if p.z >= -1e-4 {
            return None;
        }
        // Tangents times pixels per tangent: panel pixels from the
        // view's centre, y up.
        xs.push(p.x / -p.z * ppt);
        ys.push(p.y / -p.z * ppt);
    }
    let (min_x, max_x) = xs
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    let (min_y, max_y) = ys
        .iter()
        .fold((f32::MAX, f32::MIN), |(a, b), &y| (a.min(y), b.max(y)));
    let (centre, px, region) = cut_to_view([min_x, max_x, min_y, max_y], info.view_size(v))?;
    let (cx, cy) = (centre.0 / ppt, centre.1 / ppt);
    let placement = Placement::Degrees {
        x_deg: f64::from(cx.atan().to_degrees()),
        y_deg: f64::from(cy.atan().to_degrees()),
    };
    Some((placement, px, region))
}

/// What of a quad's box a view shows: the cut box's centre (panel pixels
/// from the view's centre, y up), its size in pixels, and the part of the
/// quad's image it keeps.
pub type Cut = ((f32, f32), (usize, usize), pixels::Region);

/// A box `[min_x, max_x, min_y, max_y]` in panel pixels from a view's
/// centre (y up), cut to the view (`vw`×`vh`): the cut box's centre, its
/// size in pixels (at least one, at most the view's), and the part of the
/// box it keeps (rows from the top); None if none of it is in the view.
pub fn cut_to_view(
    [min_x, max_x, min_y, max_y]: [f32; 4],
    (vw, vh): (usize, usize),
) -> Option<Cut> {
    let (half_w, half_h) = (vw as f32 / 2.0, vh as f32 / 2.0);
    let (x0, x1) = (min_x.max(-half_w), max_x.min(half_w));
    let (y0, y1) = (min_y.max(-half_h), max_y.min(half_h));
    if x0 >= x1 || y0 >= y1 {
        return None;
    }
    let (bw, bh) = (
        (max_x - min_x).max(f32::MIN_POSITIVE),
        (max_y - min_y).max(f32::MIN_POSITIVE),
    );
    let region = if (x0, x1, y0, y1) == (min_x, max_x, min_y, max_y) {
        pixels::Region::WHOLE
    } else {
        pixels::Region([
            (x0 - min_x) / bw,
            (max_y - y1) / bh,
            (x1 - min_x) / bw,
            (max_y - y0) / bh,
        ])
    };
    let w = ((x1 - x0).round().max(1.0) as usize).min(vw);
    let h = ((y1 - y0).round().max(1.0) as usize).min(vh);
    Some((((x0 + x1) / 2.0, (y0 + y1) / 2.0), (w, h), region))
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: i64 = 11_111_111;

    #[test]
    fn a_frame_is_predicted_on_the_service_grid_with_the_service_lead() {
        let t = Timing {
            predicted_display_ns: 100 * P,
            period_ns: P,
        };
        // Received half a period before the prediction: the lead is half
        // a period. Asked at once, made in no time: the service's own
        // prediction.
        let received = 100 * P - P / 2;
        assert_eq!(
            next_frame(t, P / 2, received, 0, 0),
            (100 * P, 100 * P - P / 2)
        );
        // Asked a period and a bit later: the next refresh it can make.
        let (p, wake) = next_frame(t, P / 2, received + P + 1, 0, 0);
        assert_eq!(p, 102 * P);
        assert_eq!(wake, p - P / 2);
        // Never the same refresh twice.
        assert_eq!(next_frame(t, P / 2, received, 100 * P, 0).0, 101 * P);
        assert_eq!(next_frame(t, P / 2, received, 103 * P, 0).0, 104 * P);
        // A frame that takes 0.7 of a period to make misses the refresh
        // the service predicts for a submission now: it is given the next,
        // and starts early enough for it.
        let (p, wake) = next_frame(t, P / 2, received, 0, 7 * P / 10);
        assert_eq!(p, 101 * P);
        assert_eq!(wake, p - P / 2 - 7 * P / 10);
    }
}
