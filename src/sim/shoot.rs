//! One scene's captures: the burst of frames (and the gantry's perspective frames and sweeps)
//! under one light and one traffic, and the captures of a day at its times
//! ([`super::day`]).

use super::*;

/// What every capture of a scene shares: the world, the camera, its pose and sensor, the
/// gantry. Only the light and the traffic differ between captures.
pub(super) struct Shoot<'a> {
    pub(super) world: &'a World,
    pub(super) look: &'a Appearance,
    /// Static solids the camera sees (the world's and the capture day's parked cars).
    pub(super) statics: &'a [Solid],
    pub(super) sensor: Sensor,
    pub(super) camera: &'a Camera,
    pub(super) pose_local: &'a CamFromMap,
    pub(super) rig: Option<&'a gantry::Rig>,
}

/// The frames of one capture.
pub(super) struct Burst {
    /// Fisheye frames.
    pub(super) frames: Vec<Vec<u8>>,
    /// The gantry's perspective frames (empty without a gantry).
    pub(super) perspective: Vec<Vec<u8>>,
    /// The gantry's LiDAR sweeps, one per frame (empty without a gantry).
    pub(super) sweeps: Vec<Vec<gantry::SweepPoint>>,
}

/// Vehicles and pedestrians of a capture.
pub(super) fn traffic_counts(rng: &mut ChaCha8Rng, hard: bool) -> (usize, usize) {
    if hard {
        (rng.random_range(8..15), rng.random_range(5..11))
    } else {
        (rng.random_range(3..7), rng.random_range(2..6))
    }
}

/// Per-frame auto-exposure jitter of a burst of `n`.
pub(super) fn frame_gains(rng: &mut ChaCha8Rng, n: u32) -> Vec<f64> {
    (0..n)
        .map(|_| 1.0 + rng.random_range(-0.04..0.04))
        .collect()
}

/// Seed of the sensor noise of frame `f` of capture `t` for the stream `salt`: capture 0's are
/// those of a single capture.
pub(super) fn noise_seed(world: &World, salt: u64, f: usize, t: usize) -> u64 {
    mix64(world.seed ^ (salt + f as u64) ^ ((t as u64) << 32))
}

impl Shoot<'_> {
    /// Capture `t` under a sun at `sun` (azimuth, elevation, degrees) with `movers` moving and
    /// one frame per gain: the fisheye frames, and with a gantry its perspective frames (same
    /// traffic, gains and sensor) and one LiDAR sweep per frame.
    pub(super) fn burst(
        &self,
        sun: (f64, f64),
        overcast: bool,
        (movers, gains): (&[Mover], &[f64]),
        t: usize,
    ) -> Burst {
        let light = if overcast {
            Light::from_az_el(sun.0, sun.1, 0.0, 1.0)
        } else {
            Light::from_az_el(sun.0, sun.1, 1.0, 0.3)
        };
        let view = View {
            world: self.world,
            look: self.look,
            statics: self.statics,
            light,
        };
        let dynamics: Vec<Vec<Solid>> = (0..gains.len())
            .map(|f| movers_at(self.world, movers, f as u32))
            .collect();
        let frames_of = |cam: &Camera, pose: &CamFromMap, salt: u64| {
            let base = render::static_pass(&view, cam, pose);
            let exposure = base.auto_exposure();
            gains
                .iter()
                .zip(&dynamics)
                .enumerate()
                .map(|(f, (gain, dynamic))| {
                    base.frame(
                        &view,
                        dynamic,
                        &self.sensor,
                        exposure * gain,
                        noise_seed(self.world, salt, f, t),
                    )
                })
                .collect::<Vec<_>>()
        };
        let frames = frames_of(self.camera, self.pose_local, 0xF0);
        let (perspective, sweeps) = match self.rig {
            Some(rig) => (
                frames_of(&rig.camera, &rig.pose_local, 0x9E0),
                dynamics
                    .iter()
                    .enumerate()
                    .map(|(f, dynamic)| {
                        gantry::sweep(
                            self.world,
                            self.look,
                            rig,
                            &[self.statics, dynamic],
                            noise_seed(self.world, 0x5E0, f, t),
                        )
                    })
                    .collect(),
            ),
            None => (Vec::new(), Vec::new()),
        };
        Burst {
            frames,
            perspective,
            sweeps,
        }
    }
}

/// The captures of a day (`settings.times` > 1 or a low sun; none otherwise): the times and
/// suns of [`day::day`] at the site, each capture's own overcast draw (never with a low sun or a
/// gantry, whose point is the long shadows), traffic and exposure jitter, from a generator of
/// their own so that the rest of the scene is the single capture's. The first capture keeps
/// the single capture's traffic and gains.
pub(super) fn day_captures(
    settings: &Settings,
    shoot: &Shoot,
    crs: Crs,
    origin: [f64; 2],
    first: (&[Mover], &[f64]),
) -> Result<Vec<Capture>> {
    if settings.times == 1 && !settings.low_sun {
        return Ok(Vec::new());
    }
    let hard = settings.difficulty == Difficulty::Hard;
    let gantry = shoot.rig.is_some();
    let low = settings.low_sun || gantry;
    let mut rng = ChaCha8Rng::seed_from_u64(mix64(settings.seed ^ 0xDA70_FDA7));
    let (lat, lon) = crate::geo::map_to_wgs84(crs, origin[0], origin[1])?;
    let d = day::day(&mut rng, lat, lon, settings.times, low)?;
    let (year, month, dom) = d.date;
    d.moments
        .iter()
        .enumerate()
        .map(|(t, m)| {
            let overcast = hard && !low && rng.random_bool(0.25);
            let (traffic, movers, gains) = if t == 0 {
                let n = first.0.iter().filter(|m| m.vehicle).count();
                ([n, first.0.len() - n], first.0.to_vec(), first.1.to_vec())
            } else {
                let (nv, np) = traffic_counts(&mut rng, hard);
                let movers = traffic(shoot.world, &mut rng, nv, np);
                ([nv, np], movers, frame_gains(&mut rng, settings.frames))
            };
            let sun = (m.sun_az_el_deg[0], m.sun_az_el_deg[1]);
            let b = shoot.burst(sun, overcast, (&movers, &gains), t);
            Ok(Capture {
                start: gps::UtcStart {
                    year,
                    month,
                    day: dom,
                    sec_of_day: m.sec_of_day,
                },
                sun_az_el_deg: m.sun_az_el_deg,
                overcast,
                traffic,
                frames: b.frames,
                perspective: b.perspective,
                sweeps: b.sweeps,
            })
        })
        .collect()
}
