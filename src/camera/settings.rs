//! Camera settings a capture asks for, checked before they reach the camera.

use serde::{Deserialize, Serialize};

pub use super::pixel::PixelFormat;

/// Free running or one frame per software trigger.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(rename_all = "lowercase")]
pub enum TriggerMode {
    /// The camera streams at its frame rate.
    Free,
    /// One frame per `TriggerSoftware` command.
    Software,
}

impl TriggerMode {
    /// The name in requests, rows and files (`free`, `software`).
    pub fn name(self) -> &'static str {
        match self {
            TriggerMode::Free => "free",
            TriggerMode::Software => "software",
        }
    }

    /// The mode of a name (as [`TriggerMode::name`] writes it).
    pub fn from_name(name: &str) -> Option<Self> {
        [TriggerMode::Free, TriggerMode::Software]
            .into_iter()
            .find(|t| t.name() == name)
    }
}

/// Every camera setting, resolved: what a capture is taken with (the
/// request's, or the defaults when it was accepted), what a camera is
/// configured with and reads back, and what a capture's files describe.
///
/// Why two types and no more: [`CameraSettings`] is the same settings each
/// one stated or not (a request, a change, the defaults, a catalogue row);
/// this one is the same after every gap was filled. A new setting is a field
/// in both, its line in [`CameraSettings::over`], [`CameraSettings::complete`]
/// and [`Acquisition::defaults_at`], and its device mapping (for a setting
/// with a range the camera reports, its entry in `RANGED` instead).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct Acquisition {
    /// Exposure per frame, microseconds.
    pub exposure_us: f64,
    /// Gain in the camera's units (dB for `Gain`, raw steps for `GainRaw`).
    pub gain: f64,
    /// Pixel format.
    pub pixel_format: PixelFormat,
    /// Region of interest `[x, y, width, height]` in (binned) pixels.
    #[schema(min_items = 4, max_items = 4)]
    pub region: [u32; 4],
    /// Binning `[x, y]`.
    #[schema(min_items = 2, max_items = 2)]
    pub binning: [u32; 2],
    /// Trigger mode.
    pub trigger: TriggerMode,
}

impl Acquisition {
    /// polnlos's own defaults (20 ms, gain 0, Mono16, free running) at a
    /// region and binning: what a camera is set to when it is opened.
    pub fn defaults_at(region: [u32; 4], binning: [u32; 2]) -> Self {
        Self {
            exposure_us: 20_000.0,
            gain: 0.0,
            pixel_format: PixelFormat::Mono16,
            region,
            binning,
            trigger: TriggerMode::Free,
        }
    }

    /// Whether a dark frame taken with `self` can be subtracted from a frame
    /// taken with `other`: the same exposure, gain, pixel format, region and
    /// binning (the trigger does not change the dark level).
    pub fn same_dark_as(&self, other: &Acquisition) -> bool {
        Acquisition {
            trigger: other.trigger,
            ..*self
        } == *other
    }

    /// The settings [`Acquisition::same_dark_as`] compares, as a message
    /// lists them (`exposure_us 5000, gain 0, ...`): every one but the
    /// trigger, named as in requests.
    pub fn dark_settings(&self) -> String {
        let fields = match serde_json::to_value(self) {
            Ok(serde_json::Value::Object(m)) => m,
            _ => return format!("{self:?}"),
        };
        let listed: Vec<String> = fields
            .iter()
            .filter(|(k, _)| k.as_str() != "trigger")
            .map(|(k, v)| match v {
                serde_json::Value::Number(n) => format!("{k} {}", n.as_f64().unwrap_or(f64::NAN)),
                serde_json::Value::String(s) => format!("{k} {s}"),
                v => format!("{k} {v}"),
            })
            .collect();
        listed.join(", ")
    }
}

impl From<Acquisition> for CameraSettings {
    fn from(a: Acquisition) -> Self {
        Self {
            exposure_us: Some(a.exposure_us),
            gain: Some(a.gain),
            pixel_format: Some(a.pixel_format),
            region: Some(a.region),
            binning: Some(a.binning),
            trigger: Some(a.trigger),
        }
    }
}

/// The camera settings, each one stated or not: a capture request's (what
/// it leaves out inherits the defaults), a `PUT /camera/settings` change
/// (what it leaves out keeps its default), the capture defaults themselves
/// (the region is unknown until a camera reports it), and a
/// catalogue row's (rows from before a setting was recorded lack it).
///
/// Why one type for all four: every setting inherits the same way
/// ([`CameraSettings::over`]), and the request, the camera, the catalogue
/// and the API's documents all take a new setting from here. Embedded in a
/// request body with `#[serde(flatten)]` (unknown keys are refused there).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct CameraSettings {
    /// Exposure per frame, microseconds.
    #[schema(exclusive_minimum = 0.0)]
    pub exposure_us: Option<f64>,
    /// Gain in the camera's units (dB for `Gain`, raw steps for `GainRaw`).
    pub gain: Option<f64>,
    /// Pixel format.
    pub pixel_format: Option<PixelFormat>,
    /// Region of interest `[x, y, width, height]` in (binned) pixels.
    #[schema(min_items = 4, max_items = 4)]
    pub region: Option<[u32; 4]>,
    /// Binning `[x, y]`.
    #[schema(min_items = 2, max_items = 2)]
    pub binning: Option<[u32; 2]>,
    /// `free` or `software`.
    pub trigger: Option<TriggerMode>,
}

/// Settings that were never stated, neither given nor inherited.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("no {}", missing.join(", "))]
pub struct MissingSettings {
    /// The settings' names, e.g. `region`, `trigger`.
    pub missing: Vec<&'static str>,
}

impl CameraSettings {
    /// polnlos's defaults before a camera has reported its region
    /// ([`Acquisition::defaults_at`] unbinned, without a region).
    pub fn builtin() -> Self {
        Self {
            region: None,
            ..Acquisition::defaults_at([0; 4], [1, 1]).into()
        }
    }

    /// These settings, each one that is absent taken from `base`: the one
    /// inheritance rule of every setting.
    pub fn over(&self, base: &CameraSettings) -> CameraSettings {
        CameraSettings {
            exposure_us: self.exposure_us.or(base.exposure_us),
            gain: self.gain.or(base.gain),
            pixel_format: self.pixel_format.or(base.pixel_format),
            region: self.region.or(base.region),
            binning: self.binning.or(base.binning),
            trigger: self.trigger.or(base.trigger),
        }
    }

    /// Every setting, or which are missing.
    pub fn complete(&self) -> Result<Acquisition, MissingSettings> {
        match *self {
            CameraSettings {
                exposure_us: Some(exposure_us),
                gain: Some(gain),
                pixel_format: Some(pixel_format),
                region: Some(region),
                binning: Some(binning),
                trigger: Some(trigger),
            } => Ok(Acquisition {
                exposure_us,
                gain,
                pixel_format,
                region,
                binning,
                trigger,
            }),
            s => Err(MissingSettings {
                missing: [
                    ("exposure_us", s.exposure_us.is_none()),
                    ("gain", s.gain.is_none()),
                    ("pixel_format", s.pixel_format.is_none()),
                    ("region", s.region.is_none()),
                    ("binning", s.binning.is_none()),
                    ("trigger", s.trigger.is_none()),
                ]
                .into_iter()
                .filter_map(|(name, absent)| absent.then_some(name))
                .collect(),
            }),
        }
    }
}

/// Exposure polnlos accepts at all: 10 us to one hour.
pub(crate) const EXPOSURE_RANGE_US: (f64, f64) = (10.0, 3.6e9);

/// How a GenICam feature holds its value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeatureKind {
    /// A float node (`ExposureTime`, `Gain`).
    Float,
    /// An integer node (`GainRaw`): written rounded.
    Integer,
}

/// A camera setting with a range the camera reports: its name, its GenICam
/// features, the range polnlos accepts at all, the synthetic camera's range
/// and where its value and its camera range sit. [`RANGED`] lists them; the
/// request checks, the Aravis driver and the synthetic camera read them
/// from there and name none of them.
#[derive(Clone, Copy)]
pub struct RangedSetting {
    /// Its name in requests, rows and messages (`gain`).
    pub name: &'static str,
    /// The unit its range message ends with (` microseconds`), or nothing.
    pub unit: &'static str,
    /// Its features, the SFNC name first, then older names as fallback.
    pub features: &'static [(&'static str, FeatureKind)],
    /// What polnlos accepts whatever the camera.
    pub accepted: (f64, f64),
    /// The range of the in-process synthetic camera.
    pub synthetic: (f64, f64),
    /// Its value in settings.
    pub value: fn(&Acquisition) -> f64,
    /// Its value in settings, to write it.
    pub value_mut: fn(&mut Acquisition) -> &mut f64,
    /// The camera's range and the feature that sets it.
    pub range: fn(&CameraRanges) -> ((f64, f64), &str),
    /// The same, to write them.
    pub range_mut: fn(&mut CameraRanges) -> (&mut (f64, f64), &mut String),
}

/// Every ranged camera setting: a new one (a black level) is one entry here,
/// its field in [`Acquisition`], [`CameraSettings`] and [`CameraRanges`].
pub const RANGED: &[RangedSetting] = &[
    RangedSetting {
        name: "exposure_us",
        unit: " microseconds",
        features: &[
            ("ExposureTime", FeatureKind::Float),
            ("ExposureTimeAbs", FeatureKind::Float),
        ],
        accepted: EXPOSURE_RANGE_US,
        synthetic: EXPOSURE_RANGE_US,
        value: |a| a.exposure_us,
        value_mut: |a| &mut a.exposure_us,
        range: |r| (r.exposure_us, r.exposure_feature.as_str()),
        range_mut: |r| (&mut r.exposure_us, &mut r.exposure_feature),
    },
    RangedSetting {
        name: "gain",
        unit: "",
        features: &[
            ("Gain", FeatureKind::Float),
            ("GainRaw", FeatureKind::Integer),
        ],
        accepted: (f64::NEG_INFINITY, f64::INFINITY),
        synthetic: (0.0, 10.0),
        value: |a| a.gain,
        value_mut: |a| &mut a.gain,
        range: |r| (r.gain, r.gain_feature.as_str()),
        range_mut: |r| (&mut r.gain, &mut r.gain_feature),
    },
];

/// The exposure's entry of [`RANGED`] (choosing each block's exposure needs its range).
pub(crate) const EXPOSURE: &RangedSetting = &RANGED[0];

impl RangedSetting {
    /// The range a capture may ask for: what polnlos accepts, within the
    /// camera's range once the camera has reported it.
    pub fn allowed(&self, camera: Option<&CameraRanges>) -> (f64, f64) {
        let (mut lo, mut hi) = self.accepted;
        if let Some(((a, b), _)) = camera.map(self.range) {
            (lo, hi) = (lo.max(a), hi.min(b));
        }
        (lo, hi)
    }

    /// Its feature names as a message lists them (`Gain or GainRaw`).
    pub fn feature_names(&self) -> String {
        let names: Vec<&str> = self.features.iter().map(|f| f.0).collect();
        names.join(" or ")
    }
}

/// A ranged setting of a request outside what it may be: its name, the
/// value asked for, the range and its unit.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{setting} = {value}: must be from {min} to {max}{unit}")]
pub struct OutOfRange {
    /// The request's key (`exposure_us`, `gain`).
    pub setting: &'static str,
    /// The value asked for.
    pub value: f64,
    /// The lowest value allowed.
    pub min: f64,
    /// The highest value allowed.
    pub max: f64,
    /// The unit, with its leading space (` microseconds`), or empty.
    pub unit: &'static str,
}

impl OutOfRange {
    /// `Ok` when `value` is within `min..=max` (NaN never is), else the error
    /// naming `setting`.
    pub fn check(
        setting: &'static str,
        value: f64,
        (min, max): (f64, f64),
        unit: &'static str,
    ) -> Result<(), Self> {
        if (min..=max).contains(&value) {
            return Ok(());
        }
        Err(Self {
            setting,
            value,
            min,
            max,
            unit,
        })
    }
}

/// Checks every ranged setting of `a` against [`RangedSetting::allowed`]:
/// the error names the setting, its value and the range.
pub fn check_ranges(a: &Acquisition, camera: Option<&CameraRanges>) -> Result<(), OutOfRange> {
    for r in RANGED {
        OutOfRange::check(r.name, (r.value)(a), r.allowed(camera), r.unit)?;
    }
    Ok(())
}

/// The camera's range of each ranged setting and the feature that sets it
/// (one pair of fields per entry of `RANGED`), as `GET /camera` shows them.
#[derive(Debug, Clone, Default, PartialEq, Serialize, utoipa::ToSchema)]
pub struct CameraRanges {
    /// Exposure range in microseconds and the feature that sets it.
    pub exposure_us: (f64, f64),
    /// Feature used for exposure (`ExposureTime` or `ExposureTimeAbs`).
    pub exposure_feature: String,
    /// Gain range and the feature that sets it.
    pub gain: (f64, f64),
    /// Feature used for gain (`Gain` or `GainRaw`).
    pub gain_feature: String,
}

impl CameraRanges {
    /// Ranges filled from the table: `of` gives each setting's range and feature.
    pub fn from_table<E>(
        mut of: impl FnMut(&RangedSetting) -> Result<((f64, f64), String), E>,
    ) -> Result<Self, E> {
        let mut ranges = Self::default();
        for r in RANGED {
            let (range, feature) = (r.range_mut)(&mut ranges);
            (*range, *feature) = of(r)?;
        }
        Ok(ranges)
    }

    /// The in-process synthetic camera's ranges (each first feature name).
    pub fn synthetic() -> Self {
        let filled = Self::from_table(|r| {
            Ok::<_, std::convert::Infallible>((r.synthetic, r.features[0].0.to_string()))
        });
        match filled {
            Ok(ranges) => ranges,
            Err(never) => match never {},
        }
    }
}

/// What the sensor allows for region and binning, read from the camera's
/// feature nodes when it is opened (SensorWidth/Height, Width/Height minimum
/// and increment, OffsetX/Y increment, BinningHorizontal/Vertical maximum).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct SensorLimits {
    /// Sensor width and height, unbinned pixels.
    pub sensor: [u32; 2],
    /// Smallest region width and height.
    pub min_size: [u32; 2],
    /// Region width and height must be multiples of these.
    pub size_increment: [u32; 2],
    /// Region offsets must be multiples of these.
    pub offset_increment: [u32; 2],
    /// Largest binning factors (1 when the camera cannot bin).
    pub max_binning: [u32; 2],
}

impl Default for SensorLimits {
    fn default() -> Self {
        Self {
            sensor: [0, 0],
            min_size: [1, 1],
            size_increment: [1, 1],
            offset_increment: [1, 1],
            max_binning: [1, 1],
        }
    }
}

/// A region or binning the sensor cannot deliver, naming the limit.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GeometryError {
    /// A binning factor outside `1..=max`.
    #[error("binning = {given:?}: each factor must be from 1 to {max:?} (BinningHorizontal, BinningVertical)")]
    Binning {
        /// As asked.
        given: [u32; 2],
        /// The camera's maximum.
        max: [u32; 2],
    },
    /// A region that does not fit the (binned) sensor.
    #[error("region = {given:?}: must fit the {binned:?}-pixel sensor at binning {binning:?} (x + width <= {}, y + height <= {}), with width and height at least {min_size:?}", binned[0], binned[1])]
    Outside {
        /// As asked.
        given: [u32; 4],
        /// Binning in force.
        binning: [u32; 2],
        /// Sensor size after binning.
        binned: [u32; 2],
        /// Smallest width and height.
        min_size: [u32; 2],
    },
    /// A region size or offset that is not a multiple of the camera's increment.
    #[error("region = {given:?}: {what} must be multiples of {increment:?}")]
    Increment {
        /// As asked.
        given: [u32; 4],
        /// "width and height" or "x and y".
        what: &'static str,
        /// The camera's increments.
        increment: [u32; 2],
    },
}

impl SensorLimits {
    /// Checks a region (in binned pixels) and binning against these limits,
    /// before anything reaches the camera; a region or binning absent from
    /// the request is the camera's `current` one.
    pub fn check(&self, region: [u32; 4], binning: [u32; 2]) -> Result<(), GeometryError> {
        if binning
            .iter()
            .zip(&self.max_binning)
            .any(|(&b, &m)| b < 1 || b > m)
        {
            return Err(GeometryError::Binning {
                given: binning,
                max: self.max_binning,
            });
        }
        let binned = [self.sensor[0] / binning[0], self.sensor[1] / binning[1]];
        let [x, y, w, h] = region;
        let fits = |o: u32, s: u32, max: u32, min: u32| {
            s >= min.max(1) && o.checked_add(s).is_some_and(|e| e <= max)
        };
        if !(fits(x, w, binned[0], self.min_size[0]) && fits(y, h, binned[1], self.min_size[1])) {
            return Err(GeometryError::Outside {
                given: region,
                binning,
                binned,
                min_size: self.min_size,
            });
        }
        let multiple = |v: u32, inc: u32| v.is_multiple_of(inc.max(1));
        if !(multiple(w, self.size_increment[0]) && multiple(h, self.size_increment[1])) {
            return Err(GeometryError::Increment {
                given: region,
                what: "width and height",
                increment: self.size_increment,
            });
        }
        if !(multiple(x, self.offset_increment[0]) && multiple(y, self.offset_increment[1])) {
            return Err(GeometryError::Increment {
                given: region,
                what: "x and y",
                increment: self.offset_increment,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_dark_fits_a_capture_with_the_same_settings_whatever_its_trigger() {
        let light = Acquisition {
            exposure_us: 5000.0,
            gain: 2.0,
            pixel_format: PixelFormat::Mono16,
            region: [0, 0, 64, 32],
            binning: [1, 1],
            trigger: TriggerMode::Software,
        };
        let dark = Acquisition {
            trigger: TriggerMode::Free,
            ..light
        };
        assert!(dark.same_dark_as(&light));
        for other in [
            Acquisition {
                exposure_us: 5001.0,
                ..dark
            },
            Acquisition { gain: 0.0, ..dark },
            Acquisition {
                pixel_format: PixelFormat::Mono8,
                ..dark
            },
            Acquisition {
                region: [1, 0, 64, 32],
                ..dark
            },
            Acquisition {
                binning: [2, 2],
                ..dark
            },
        ] {
            assert!(!other.same_dark_as(&light), "{other:?}");
        }
        let camera = CameraSettings::from(light);
        assert_eq!(
            (camera.region, camera.binning),
            (Some(light.region), Some(light.binning))
        );
    }

    #[test]
    fn each_ranged_entry_reads_and_writes_its_own_field_and_one_message_checks_all() {
        for (k, r) in RANGED.iter().enumerate() {
            let v = 1234.5 + k as f64;
            let mut a = Acquisition::defaults_at([0, 0, 8, 8], [1, 1]);
            *(r.value_mut)(&mut a) = v;
            assert_eq!(serde_json::to_value(a).unwrap()[r.name], v, "{}", r.name);
            assert_eq!((r.value)(&a), v);
            let stated = serde_json::to_value(CameraSettings::from(a)).unwrap();
            assert_eq!(stated[r.name], v, "{}", r.name);
            let mut ranges = CameraRanges::default();
            let (range, feature) = (r.range_mut)(&mut ranges);
            (*range, *feature) = ((v, v + 1.0), r.features[0].0.into());
            let shown = serde_json::to_value(&ranges).unwrap();
            assert_eq!(shown[r.name], serde_json::json!([v, v + 1.0]), "{}", r.name);
            assert_eq!((r.range)(&ranges), ((v, v + 1.0), r.features[0].0));
            assert!(r.allowed(Some(&ranges)).0 >= r.accepted.0);
        }
        let defaults = Acquisition::defaults_at([0, 0, 8, 8], [1, 1]);
        let check_ranges = |a: &Acquisition, c: Option<&CameraRanges>| {
            check_ranges(a, c).map_err(|e| e.to_string())
        };
        let synthetic = CameraRanges::synthetic();
        assert_eq!(check_ranges(&defaults, Some(&synthetic)), Ok(()));
        assert_eq!(
            check_ranges(
                &Acquisition {
                    gain: 11.0,
                    ..defaults
                },
                Some(&synthetic)
            ),
            Err("gain = 11: must be from 0 to 10".to_string())
        );
        assert_eq!(
            check_ranges(
                &Acquisition {
                    exposure_us: 5.0,
                    ..defaults
                },
                None
            ),
            Err("exposure_us = 5: must be from 10 to 3600000000 microseconds".to_string())
        );
        assert_eq!(
            (
                synthetic.exposure_feature.as_str(),
                synthetic.gain_feature.as_str()
            ),
            ("ExposureTime", "Gain")
        );
        assert_eq!(RANGED[1].feature_names(), "Gain or GainRaw");
        let dark = defaults.dark_settings();
        assert!(
            dark.contains("gain 0,") && dark.contains("exposure_us 20000,"),
            "{dark}"
        );
        assert!(dark.contains("pixel_format Mono16"), "{dark}");
        assert!(!dark.contains("trigger"), "{dark}");
    }

    /// Aravis's fake camera: 2048 x 2048, sizes and offsets by 1, binning to 16.
    const FAKE: SensorLimits = SensorLimits {
        sensor: [2048, 2048],
        min_size: [1, 1],
        size_increment: [1, 1],
        offset_increment: [1, 1],
        max_binning: [16, 16],
    };

    #[test]
    fn geometry_inside_the_sensor_passes_and_outside_names_the_limit() {
        FAKE.check([0, 0, 512, 512], [1, 1]).unwrap();
        FAKE.check([0, 0, 2048, 2048], [1, 1]).unwrap();
        FAKE.check([0, 0, 1024, 1024], [2, 2]).unwrap();
        let cases = [
            ([0, 0, 100_000, 100_000], [1, 1], "2048"),
            ([2_147_483_647, 0, 10, 10], [1, 1], "x + width"),
            (
                [u32::MAX, u32::MAX, u32::MAX, u32::MAX],
                [1, 1],
                "x + width",
            ),
            ([0, 0, 0, 0], [1, 1], "at least"),
            ([0, 0, 1025, 1024], [2, 2], "1024"),
            ([0, 0, 10, 10], [100_000, 100_000], "from 1 to [16, 16]"),
            ([0, 0, 10, 10], [0, 1], "from 1 to"),
        ];
        for (region, binning, says) in cases {
            let e = FAKE.check(region, binning).unwrap_err().to_string();
            assert!(e.contains(says), "{region:?} {binning:?}: {e}");
        }
        let coarse = SensorLimits {
            size_increment: [16, 2],
            offset_increment: [8, 8],
            min_size: [64, 64],
            ..FAKE
        };
        coarse.check([8, 8, 64, 64], [1, 1]).unwrap();
        assert!(matches!(
            coarse.check([8, 8, 72, 64], [1, 1]),
            Err(GeometryError::Increment { .. })
        ));
        assert!(matches!(
            coarse.check([4, 8, 64, 64], [1, 1]),
            Err(GeometryError::Increment { .. })
        ));
        assert!(matches!(
            coarse.check([0, 0, 32, 64], [1, 1]),
            Err(GeometryError::Outside { .. })
        ));
    }

    #[test]
    fn settings_refuse_negative_regions_and_short_arrays() {
        let ok = r#"{"exposure_us": 1000, "gain": 0, "pixel_format": "Mono16", "trigger": "free", "region": [0, 0, 64, 64], "binning": [1, 1]}"#;
        let read: CameraSettings = serde_json::from_str(ok).unwrap();
        assert_eq!(read.complete().unwrap().region, [0, 0, 64, 64]);
        for bad in [
            ok.replace("[0, 0, 64, 64]", "[-1, -1, 10, 10]"),
            ok.replace("[0, 0, 64, 64]", "[0, 0, 64]"),
            ok.replace("\"free\"", "\"sometimes\""),
        ] {
            assert!(
                serde_json::from_str::<CameraSettings>(&bad).is_err(),
                "{bad}"
            );
        }
    }

    #[test]
    fn every_setting_inherits_the_same_way_and_a_gap_is_named() {
        let base = CameraSettings::from(Acquisition::defaults_at([0, 0, 64, 32], [2, 2]));
        let stated = CameraSettings {
            gain: Some(3.0),
            trigger: Some(TriggerMode::Software),
            ..CameraSettings::default()
        };
        let got = stated.over(&base).complete().unwrap();
        assert_eq!(
            got,
            Acquisition {
                gain: 3.0,
                trigger: TriggerMode::Software,
                ..Acquisition::defaults_at([0, 0, 64, 32], [2, 2])
            }
        );
        assert_eq!(CameraSettings::from(got).over(&stated), got.into());
        let gap = stated
            .over(&CameraSettings::builtin())
            .complete()
            .unwrap_err();
        assert_eq!(gap.missing, ["region"]);
        assert_eq!(gap.to_string(), "no region");
        assert_eq!(
            CameraSettings::default()
                .complete()
                .unwrap_err()
                .missing
                .len(),
            6
        );
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 512, rng_seed: proptest::test_runner::RngSeed::Fixed(8), ..Default::default() })]
        /// Whatever is asked, an accepted geometry fits the sensor, so the
        /// frame's byte count (16-bit) cannot overflow the camera's u32 payload.
        #[test]
        fn accepted_geometry_fits_the_sensor(
            region in proptest::array::uniform4(proptest::prop_oneof![0u32..4096, proptest::num::u32::ANY]),
            binning in proptest::array::uniform2(proptest::prop_oneof![0u32..20, proptest::num::u32::ANY]),
        ) {
            if FAKE.check(region, binning).is_ok() {
                proptest::prop_assert!(region[0] + region[2] <= 2048 / binning[0]);
                proptest::prop_assert!(region[1] + region[3] <= 2048 / binning[1]);
                proptest::prop_assert!(u64::from(region[2]) * u64::from(region[3]) * 2 <= u64::from(u32::MAX));
            }
        }
    }

    #[test]
    fn names_round_trip_and_full_scale_follows_the_bits() {
        for f in [PixelFormat::Mono8, PixelFormat::Mono12, PixelFormat::Mono16] {
            assert_eq!(PixelFormat::from_name(f.name()), Some(f));
        }
        assert_eq!(PixelFormat::from_name("RGB8"), None);
        for t in [TriggerMode::Free, TriggerMode::Software] {
            assert_eq!(TriggerMode::from_name(t.name()), Some(t));
            assert_eq!(serde_json::to_value(t).unwrap(), t.name());
        }
        assert_eq!(PixelFormat::Mono8.full_scale(), 255.0);
        assert_eq!(PixelFormat::Mono12.full_scale(), 4095.0);
        assert_eq!(PixelFormat::Mono16.full_scale(), 65535.0);
    }
}
