//! What a lane map's lanes were derived from, and how: the traffic side, the road classes used,
//! the offset model of unmarked streets, and per lane its road class and what its geometry rests
//! on (tags or defaults). A tile records all of it, so that a corrector can refuse a map whose
//! geometry its method was not designed for, and a covariance can say how far to trust a lane.

use serde::{Deserialize, Serialize};

/// Which side of the road traffic keeps to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Traffic {
    /// Right-hand traffic (continental Europe, the Americas).
    #[default]
    Right,
    /// Left-hand traffic (UK, Japan, ...).
    Left,
}

impl Traffic {
    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Traffic::Right => "right",
            Traffic::Left => "left",
        }
    }
}

impl std::str::FromStr for Traffic {
    type Err = crate::names::NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        crate::names::parse_name(s)
    }
}

/// The road class of a lane: its OpenStreetMap `highway` value, or where else it came from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
#[repr(u8)]
pub enum RoadClass {
    /// Not known (lanes given as CSV).
    #[default]
    Unknown = 0,
    /// `highway=motorway`.
    Motorway = 1,
    /// `highway=trunk`.
    Trunk = 2,
    /// `highway=primary`.
    Primary = 3,
    /// `highway=secondary`.
    Secondary = 4,
    /// `highway=tertiary`.
    Tertiary = 5,
    /// `highway=unclassified`.
    Unclassified = 6,
    /// `highway=residential`.
    Residential = 7,
    /// `highway=living_street`.
    LivingStreet = 8,
    /// `highway=service`.
    Service = 9,
    /// `highway=motorway_link`.
    MotorwayLink = 10,
    /// `highway=trunk_link`.
    TrunkLink = 11,
    /// `highway=primary_link`.
    PrimaryLink = 12,
    /// `highway=secondary_link`.
    SecondaryLink = 13,
    /// `highway=tertiary_link`.
    TertiaryLink = 14,
    /// A lanelet of a Lanelet2 (HD) map: surveyed lane geometry.
    Lanelet = 15,
}

impl RoadClass {
    /// Every class, in code order.
    pub const ALL: [RoadClass; 16] = [
        RoadClass::Unknown,
        RoadClass::Motorway,
        RoadClass::Trunk,
        RoadClass::Primary,
        RoadClass::Secondary,
        RoadClass::Tertiary,
        RoadClass::Unclassified,
        RoadClass::Residential,
        RoadClass::LivingStreet,
        RoadClass::Service,
        RoadClass::MotorwayLink,
        RoadClass::TrunkLink,
        RoadClass::PrimaryLink,
        RoadClass::SecondaryLink,
        RoadClass::TertiaryLink,
        RoadClass::Lanelet,
    ];

    /// The name: the OSM `highway` value for OSM classes, `lanelet` and `unknown` otherwise.
    pub fn name(self) -> &'static str {
        match self {
            RoadClass::Unknown => "unknown",
            RoadClass::Motorway => "motorway",
            RoadClass::Trunk => "trunk",
            RoadClass::Primary => "primary",
            RoadClass::Secondary => "secondary",
            RoadClass::Tertiary => "tertiary",
            RoadClass::Unclassified => "unclassified",
            RoadClass::Residential => "residential",
            RoadClass::LivingStreet => "living_street",
            RoadClass::Service => "service",
            RoadClass::MotorwayLink => "motorway_link",
            RoadClass::TrunkLink => "trunk_link",
            RoadClass::PrimaryLink => "primary_link",
            RoadClass::SecondaryLink => "secondary_link",
            RoadClass::TertiaryLink => "tertiary_link",
            RoadClass::Lanelet => "lanelet",
        }
    }

    /// The classes of OSM `highway` values lanes can be derived from, in code order.
    pub fn osm() -> impl Iterator<Item = RoadClass> {
        RoadClass::ALL
            .into_iter()
            .filter(|c| !matches!(c, RoadClass::Unknown | RoadClass::Lanelet))
    }

    /// The class of an OSM `highway` value lanes can be derived from.
    pub fn from_osm(highway: &str) -> Option<RoadClass> {
        RoadClass::osm().find(|c| c.name() == highway)
    }

    /// The class stored under `code`, if any.
    pub fn from_code(code: u8) -> Option<RoadClass> {
        RoadClass::ALL.get(code as usize).copied()
    }

    /// True for the `_link` classes (ramps and connectors).
    pub fn is_link(self) -> bool {
        matches!(
            self,
            RoadClass::MotorwayLink
                | RoadClass::TrunkLink
                | RoadClass::PrimaryLink
                | RoadClass::SecondaryLink
                | RoadClass::TertiaryLink
        )
    }
}

impl std::str::FromStr for RoadClass {
    type Err = crate::names::NameError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        crate::names::parse_name(s)
    }
}

/// A set of road classes (bit `code` set for each class in it).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RoadClasses(u32);

impl RoadClasses {
    /// The OSM classes lanes are derived from by default: motorway to living_street and their
    /// links (not `service`).
    pub const DEFAULT: RoadClasses = RoadClasses(
        1 << RoadClass::Motorway as u32
            | 1 << RoadClass::Trunk as u32
            | 1 << RoadClass::Primary as u32
            | 1 << RoadClass::Secondary as u32
            | 1 << RoadClass::Tertiary as u32
            | 1 << RoadClass::Unclassified as u32
            | 1 << RoadClass::Residential as u32
            | 1 << RoadClass::LivingStreet as u32
            | 1 << RoadClass::MotorwayLink as u32
            | 1 << RoadClass::TrunkLink as u32
            | 1 << RoadClass::PrimaryLink as u32
            | 1 << RoadClass::SecondaryLink as u32
            | 1 << RoadClass::TertiaryLink as u32,
    );

    /// No class.
    pub const EMPTY: RoadClasses = RoadClasses(0);

    /// The set from its bits; `None` when a bit names no class.
    pub fn from_bits(bits: u32) -> Option<RoadClasses> {
        (bits >> RoadClass::ALL.len() == 0).then_some(RoadClasses(bits))
    }

    /// The bits.
    pub fn bits(self) -> u32 {
        self.0
    }

    /// True when `class` is in the set.
    pub fn contains(self, class: RoadClass) -> bool {
        self.0 & (1 << class as u32) != 0
    }

    /// The set with `class` added.
    pub fn with(self, class: RoadClass) -> RoadClasses {
        RoadClasses(self.0 | 1 << class as u32)
    }

    /// The classes in the set, in code order.
    pub fn iter(self) -> impl Iterator<Item = RoadClass> {
        RoadClass::ALL
            .into_iter()
            .filter(move |&c| self.contains(c))
    }

    /// Parses a comma-separated list of the OSM `highway` values lanes can be derived from
    /// (`motorway,primary,service`); an empty name, `lanelet` or `unknown` (classes no OSM way
    /// has) is refused with the names that are expected.
    pub fn parse_list(list: &str) -> Result<RoadClasses, crate::names::NameError> {
        list.split(',')
            .map(|name| {
                let name = name.trim();
                RoadClass::from_osm(name).ok_or_else(|| {
                    let expected: Vec<String> = RoadClass::osm()
                        .map(|c| format!("`{}`", c.name()))
                        .collect();
                    let what = if name.is_empty() {
                        "an empty class name".to_string()
                    } else {
                        format!("unknown class `{}`", crate::input::quote(name))
                    };
                    crate::names::NameError::new(format!(
                        "{what} in a comma-separated list, expected OSM highway values: {}",
                        expected.join(", ")
                    ))
                })
            })
            .try_fold(RoadClasses::EMPTY, |set, c| Ok(set.with(c?)))
    }
}

impl std::fmt::Display for RoadClasses {
    /// The class names, comma-separated.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: Vec<&str> = self.iter().map(RoadClass::name).collect();
        f.write_str(&names.join(","))
    }
}

/// What one lane's geometry rests on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct LaneInfo {
    /// Its road class.
    pub class: RoadClass,
    /// [`LaneInfo::LANES_TAGGED`] and the other flags.
    pub flags: u8,
}

impl LaneInfo {
    /// The lane count of its way came from a `lanes`, `lanes:forward` or `lanes:backward` tag
    /// (otherwise it was inferred from the road class and `oneway`).
    pub const LANES_TAGGED: u8 = 1;
    /// Its width came from the way's `width` tag (otherwise the class default).
    pub const WIDTH_TAGGED: u8 = 1 << 1;
    /// An unmarked two-way street: placed with the unmarked-street offset model.
    pub const UNMARKED: u8 = 1 << 2;
    /// It runs against its way's direction.
    pub const BACKWARD: u8 = 1 << 3;
    /// One lane shared by both directions (on the way line).
    pub const SHARED: u8 = 1 << 4;
    /// Every flag this build knows.
    pub const ALL_FLAGS: u8 = (1 << 5) - 1;

    /// A lane of `class` with `flags`.
    pub fn new(class: RoadClass, flags: u8) -> LaneInfo {
        LaneInfo { class, flags }
    }

    /// True when every flag of `flag` is set.
    pub fn has(self, flag: u8) -> bool {
        self.flags & flag == flag
    }
}

/// The largest unmarked-street offset scale lanes may be derived with: an unmarked street has a
/// lane each way, nominally half a lane width from the way line; at 2 they lie on the road's
/// edges, beyond it off the road. 0 puts both on the way line.
pub const MAX_UNMARKED_OFFSET_SCALE: f64 = 2.0;

/// An unmarked-street offset scale outside `[0, MAX_UNMARKED_OFFSET_SCALE]` (or NaN).
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error(
    "the unmarked-street offset scale {0} is outside [0, {max}]",
    max = MAX_UNMARKED_OFFSET_SCALE
)]
pub struct UnmarkedOffsetScaleError(pub f64);

/// Checks an unmarked-street offset scale (a factor on the nominal lane offset, unitless): in
/// `[0, MAX_UNMARKED_OFFSET_SCALE]`. Every reader of one (tile header, grid manifest, config,
/// command line, Python) checks it here, so that they agree on what a map may hold.
pub fn check_unmarked_offset_scale(scale: f64) -> Result<(), UnmarkedOffsetScaleError> {
    if (0.0..=MAX_UNMARKED_OFFSET_SCALE).contains(&scale) {
        Ok(())
    } else {
        Err(UnmarkedOffsetScaleError(scale))
    }
}

/// How a map's lanes were derived (what a tile records about them).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LaneGeometry {
    /// The traffic side lanes were placed for.
    pub traffic: Traffic,
    /// The OSM road classes lanes were derived from.
    pub classes: RoadClasses,
    /// The unmarked-street offset scale of lanes derived from raw OSM ways; `None` when no lane
    /// came from raw OSM (Lanelet2 or CSV lanes only), so no method's lane model applies.
    pub unmarked_offset_scale: Option<f64>,
}

impl Default for LaneGeometry {
    /// Right-hand traffic, the default classes, lanealign's unmarked-street model (0.5).
    fn default() -> Self {
        LaneGeometry {
            traffic: Traffic::Right,
            classes: RoadClasses::DEFAULT,
            unmarked_offset_scale: Some(crate::params::UNMARKED_OFFSET_SCALE),
        }
    }
}

impl std::fmt::Display for LaneGeometry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} traffic, classes {}",
            self.traffic.name(),
            self.classes
        )?;
        match self.unmarked_offset_scale {
            Some(scale) => write!(f, ", unmarked-street offset scale {scale}"),
            None => write!(f, ", no lanes from raw OSM ways"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unmarked_offset_scale_is_a_factor_from_0_to_2() {
        for ok in [0.0, -0.0, 0.5, 1.0, MAX_UNMARKED_OFFSET_SCALE] {
            assert_eq!(check_unmarked_offset_scale(ok), Ok(()), "{ok}");
        }
        for bad in [
            -1e-300,
            2.000_000_1,
            f64::NAN,
            f64::INFINITY,
            f64::NEG_INFINITY,
        ] {
            let err = check_unmarked_offset_scale(bad).unwrap_err();
            assert_eq!(err.0.to_bits(), bad.to_bits());
            assert!(err.to_string().contains("outside [0, 2]"), "{err}");
        }
    }

    #[test]
    fn names_are_the_serde_names_and_osm_values() {
        for c in RoadClass::ALL {
            assert_eq!(c.name().parse::<RoadClass>(), Ok(c));
            assert_eq!(RoadClass::from_code(c as u8), Some(c));
        }
        assert_eq!(
            RoadClass::from_osm("living_street"),
            Some(RoadClass::LivingStreet)
        );
        assert_eq!(RoadClass::from_osm("lanelet"), None);
        assert_eq!(RoadClass::from_osm("footway"), None);
        assert_eq!(Traffic::Left.name().parse::<Traffic>(), Ok(Traffic::Left));
    }

    #[test]
    fn class_sets_round_trip_through_bits_and_lists() {
        let set = RoadClasses::parse_list("motorway, service").unwrap();
        assert!(set.contains(RoadClass::Service) && !set.contains(RoadClass::Primary));
        assert_eq!(RoadClasses::from_bits(set.bits()), Some(set));
        assert_eq!(RoadClasses::from_bits(1 << 20), None);
        assert_eq!(set.to_string(), "motorway,service");
        assert_eq!(RoadClasses::DEFAULT.iter().count(), 13);
        assert!(RoadClasses::parse_list("motorway,footway").is_err());
    }

    #[test]
    fn class_lists_take_only_osm_highway_values() {
        for (list, said) in [
            ("lanelet", "unknown class `lanelet`"),
            ("primary,unknown", "unknown class `unknown`"),
            (",", "an empty class name"),
            ("primary,,secondary", "an empty class name"),
        ] {
            let message = RoadClasses::parse_list(list).unwrap_err().to_string();
            assert!(message.starts_with(said), "{list}: {message}");
            let (_, expected) = message.split_once("expected").unwrap();
            assert!(
                expected.contains("`motorway`")
                    && !expected.contains("`lanelet`")
                    && !expected.contains("`unknown`"),
                "{list}: {message}"
            );
        }
    }
}
