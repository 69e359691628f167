//! The colour channels of a colour measurement.
//!
//! Why here, at the bottom: the measurement (a colour camera's frames) and
//! the report of a reconstruction (each colour's own fit) both name them.

/// A colour channel of an RGB measurement, in the order arrays hold them.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize, utoipa::ToSchema,
)]
#[serde(rename_all = "lowercase")]
pub enum Colour {
    /// Red.
    Red,
    /// Green.
    Green,
    /// Blue.
    Blue,
}

impl Colour {
    /// Red, green, blue: the order of a measurement's channels and of an RGB image.
    pub const ALL: [Colour; 3] = [Colour::Red, Colour::Green, Colour::Blue];

    /// `red`, `green` or `blue`, as the files and reports name it.
    pub fn name(self) -> &'static str {
        match self {
            Colour::Red => "red",
            Colour::Green => "green",
            Colour::Blue => "blue",
        }
    }
}
