//! String forms of the engines' enums: one spelling per variant (the CLI's and the scene
//! file's), shared by `FromStr`, `Display` and serde. Used by blueshift-tracking and
//! blueshift-doppler, which may not import each other.

/// Serde through the string form: serialises with `Display`, deserialises a string with
/// `FromStr` (so a scene file and a flag refuse a bad spelling with the same message).
#[macro_export]
macro_rules! serde_via_str {
    ($t:ty) => {
        impl serde::Serialize for $t {
            fn serialize<S: serde::Serializer>(
                &self,
                serializer: S,
            ) -> std::result::Result<S::Ok, S::Error> {
                serializer.collect_str(self)
            }
        }

        impl<'de> serde::Deserialize<'de> for $t {
            fn deserialize<D: serde::Deserializer<'de>>(
                deserializer: D,
            ) -> std::result::Result<Self, D::Error> {
                let s = <String as serde::Deserialize>::deserialize(deserializer)?;
                s.parse().map_err(serde::de::Error::custom)
            }
        }
    };
}

/// A unit enum's spellings: `ALL`, `NAMES`, `name()`, `FromStr` (the spellings plus
/// aliases; anything else is the invoking crate's `Error::UnknownName`, made by its
/// `Error::unknown(what, given, NAMES)`), `Display` (the spelling) and serde through them.
/// The invoking crate needs `serde` and an `Error`/`Result` with that constructor.
#[macro_export]
// `crate::Error` and `crate::Result` are the invoking crate's on purpose: each engine's
// names fail with its own error type.
#[allow(clippy::crate_in_macro_def)]
macro_rules! named_enum {
    (
        $t:ident, $what:literal,
        [$($v:ident => $name:literal),+ $(,)?]
        $(, aliases [$($alias:literal => $av:ident),+ $(,)?])?
    ) => {
        impl $t {
            #[doc = concat!("Every ", $what, ", in the order of [`", stringify!($t), "::NAMES`].")]
            pub const ALL: &'static [$t] = &[$($t::$v),+];
            #[doc = concat!("The spellings of [`", stringify!($t), "::ALL`].")]
            pub const NAMES: &'static [&'static str] = &[$($name),+];

            /// Its spelling (as the CLI and scene files write it).
            #[must_use]
            pub fn name(self) -> &'static str {
                match self {
                    $($t::$v => $name),+
                }
            }
        }

        impl std::str::FromStr for $t {
            type Err = crate::Error;
            fn from_str(s: &str) -> crate::Result<Self> {
                match s {
                    $($name => Ok($t::$v),)+
                    $($($alias => Ok($t::$av),)+)?
                    other => Err(crate::Error::unknown($what, other, $t::NAMES)),
                }
            }
        }

        impl std::fmt::Display for $t {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.name())
            }
        }

        $crate::serde_via_str!($t);
    };
}
