//! The reference Brewster-angle bench scenes, built into the binary.

/// (name, TOML text) of every built-in scene.
pub const BUILT_IN: &[(&str, &str)] = &[
    (
        "brewster-crossed-3x3",
        include_str!("../../config/scenes/brewster-crossed-3x3.toml"),
    ),
    (
        "brewster-crossed",
        include_str!("../../config/scenes/brewster-crossed.toml"),
    ),
    (
        "brewster-multi-3x3",
        include_str!("../../config/scenes/brewster-multi-3x3.toml"),
    ),
    (
        "brewster-multi",
        include_str!("../../config/scenes/brewster-multi.toml"),
    ),
    (
        "brewster-mosaic-3x3",
        include_str!("../../config/scenes/brewster-mosaic-3x3.toml"),
    ),
    (
        "brewster-mosaic",
        include_str!("../../config/scenes/brewster-mosaic.toml"),
    ),
    (
        "brewster-nopol-3x3",
        include_str!("../../config/scenes/brewster-nopol-3x3.toml"),
    ),
    (
        "brewster-nopol",
        include_str!("../../config/scenes/brewster-nopol.toml"),
    ),
    (
        "brewster-rotating-3x3",
        include_str!("../../config/scenes/brewster-rotating-3x3.toml"),
    ),
    (
        "brewster-rotating",
        include_str!("../../config/scenes/brewster-rotating.toml"),
    ),
    (
        "occluder-crossed-3x3",
        include_str!("../../config/scenes/occluder-crossed-3x3.toml"),
    ),
    (
        "occluder-crossed",
        include_str!("../../config/scenes/occluder-crossed.toml"),
    ),
    (
        "occluder-multi-3x3",
        include_str!("../../config/scenes/occluder-multi-3x3.toml"),
    ),
    (
        "occluder-multi",
        include_str!("../../config/scenes/occluder-multi.toml"),
    ),
    (
        "occluder-nopol-3x3",
        include_str!("../../config/scenes/occluder-nopol-3x3.toml"),
    ),
    (
        "occluder-nopol",
        include_str!("../../config/scenes/occluder-nopol.toml"),
    ),
    (
        "occluder-rotating-3x3",
        include_str!("../../config/scenes/occluder-rotating-3x3.toml"),
    ),
    (
        "occluder-rotating",
        include_str!("../../config/scenes/occluder-rotating.toml"),
    ),
];

/// The TOML text of the built-in scene `name`.
pub fn text(name: &str) -> Option<&'static str> {
    BUILT_IN.iter().find(|(n, _)| *n == name).map(|(_, t)| *t)
}
