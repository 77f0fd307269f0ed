//! Target classes: the size, speed, skin and heating a dataset draws a target of each kind from.
//!
//! A target is an ellipsoid (semi-axes along the velocity, across, up). For winged aircraft the across axis is a
//! quarter of the span, not half: an ellipsoid as wide as the wings would have several times the wings' area in
//! a view from below or ahead. Sizes are drawn ×0.8–1.2 around the values here. Sources of the dimensions and
//! speeds are the manufacturers' published figures:
//! - small multirotor: DJI Phantom 4 (350 mm diagonal without propellers, 1.38 kg, up to 20 m/s);
//! - fixed-wing UAV: Insitu ScanEagle (1.55 m long, 3.11 m span, cruise 25–28 m/s, dash 41 m/s);
//! - light aircraft: Cessna 172S (8.28 m long, 11.0 m span, 2.72 m high, cruise 124 kn = 64 m/s);
//! - airliner: Airbus A320 (37.57 m long, 35.8 m span, 11.76 m high, cruise Mach 0.78, approach ~70 m/s);
//! - fighter: General Dynamics F-16 (15.06 m long, 9.96 m span, 4.88 m high, up to Mach 2);
//! - bird-sized clutter: a gull (about 0.6 m long, 1.4 m span, 10–15 m/s), a bird's body near 40 °C.
//!
//! Heating is the skin's excess over the stagnation temperature from what is inside (motors and batteries, an
//! engine bay, a warm body); emissivities are those of painted or composite skins (0.8–0.9) and of feathers
//! (0.95).
//!
//! Altitudes (above the ground, m) are where each kind flies:
//! - small multirotor: 5–500 m; the rules of the EU's open category and of the US Part 107 keep them within
//!   120 m (400 ft) of the ground, and the band allows for those that go higher;
//! - fixed-wing UAV: 50 m to the ScanEagle's ceiling, 5950 m (19 500 ft);
//! - light aircraft: 150 m (500 ft, the least height over open country in 14 CFR 91.119) to the Cessna 172S's
//!   service ceiling, 4270 m (14 000 ft);
//! - airliner: 300 m on approach to the A320's ceiling, 12 130 m (39 800 ft);
//! - fighter: 150 m to the F-16's ceiling, 15 240 m (50 000 ft);
//! - bird: 5–2000 m; weather-radar studies of migration find most birds below 2 km.
//!
//! Materials are Cook–Torrance parameters spanning the gloss of the skins, not measured BRDFs: a gloss
//! polyurethane airliner (`k_s` 0.6, roughness 0.2), painted aluminium (the scenario default, 0.5 and 0.3), a
//! painted composite UAV (0.4, 0.35), a moulded plastic drone shell (0.3, 0.4), low-gloss camouflage paint (0.2,
//! 0.6) and feathers (0.05, 0.8); `f0` is 0.04, a paint's or plastic's reflectance at normal incidence
//! (refractive index about 1.5).

use crate::physics::brdf::CookTorrance;

/// One class.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TargetClass {
    /// Where it flies: height above the ground, m.
    pub altitude_m: [f64; 2],
    /// Its skin's reflectance.
    pub brdf: CookTorrance,
    /// The name a dataset spec uses.
    pub name: &'static str,
    /// Ellipsoid semi-axes, m (along the velocity, across, up).
    pub semi_axes_m: [f64; 3],
    /// Speed range, m/s.
    pub speed_m_s: [f64; 2],
    /// Skin emissivity.
    pub emissivity: f64,
    /// Internal heating range, K.
    pub heating_k: [f64; 2],
}

impl TargetClass {
    /// Every class.
    pub const ALL: [Self; 6] = [
        Self {
            name: "small_multirotor",
            altitude_m: [5.0, 500.0],
            brdf: CookTorrance { kd: 0.7, ks: 0.3, f0: 0.04, roughness: 0.4 },
            semi_axes_m: [0.175, 0.175, 0.1],
            speed_m_s: [2.0, 20.0],
            emissivity: 0.85,
            heating_k: [4.0, 15.0],
        },
        Self {
            name: "fixed_wing_uav",
            altitude_m: [50.0, 5950.0],
            brdf: CookTorrance { kd: 0.6, ks: 0.4, f0: 0.04, roughness: 0.35 },
            semi_axes_m: [0.78, 0.78, 0.15],
            speed_m_s: [20.0, 41.0],
            emissivity: 0.85,
            heating_k: [5.0, 20.0],
        },
        Self {
            name: "light_aircraft",
            altitude_m: [150.0, 4270.0],
            brdf: CookTorrance { kd: 0.5, ks: 0.5, f0: 0.04, roughness: 0.3 },
            semi_axes_m: [4.14, 2.75, 1.0],
            speed_m_s: [40.0, 70.0],
            emissivity: 0.85,
            heating_k: [5.0, 30.0],
        },
        Self {
            name: "airliner",
            altitude_m: [300.0, 12130.0],
            brdf: CookTorrance { kd: 0.4, ks: 0.6, f0: 0.04, roughness: 0.2 },
            semi_axes_m: [18.8, 9.0, 2.5],
            speed_m_s: [70.0, 240.0],
            emissivity: 0.8,
            heating_k: [0.0, 20.0],
        },
        Self {
            name: "fighter",
            altitude_m: [150.0, 15240.0],
            brdf: CookTorrance { kd: 0.8, ks: 0.2, f0: 0.04, roughness: 0.6 },
            semi_axes_m: [7.5, 2.5, 1.5],
            speed_m_s: [150.0, 450.0],
            emissivity: 0.85,
            heating_k: [0.0, 40.0],
        },
        Self {
            name: "bird",
            altitude_m: [5.0, 2000.0],
            brdf: CookTorrance { kd: 0.95, ks: 0.05, f0: 0.04, roughness: 0.8 },
            semi_axes_m: [0.3, 0.35, 0.08],
            speed_m_s: [8.0, 16.0],
            emissivity: 0.95,
            heating_k: [5.0, 20.0],
        },
    ];

    /// The class called `name`.
    pub fn named(name: &str) -> Option<Self> {
        Self::ALL.iter().copied().find(|c| c.name == name)
    }
}
