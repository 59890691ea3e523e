//! String forms of the crate's enums: one spelling per variant (the CLI's and the scene
//! file's), shared by `FromStr`, `Display` and serde.

/// Serde through the string form: serialises with `Display`, deserialises a string with
/// `FromStr` (so a scene file and a flag refuse a bad spelling with the same message).
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
pub(crate) use serde_via_str;

/// A unit enum's spellings: `ALL`, `NAMES`, `name()`, `FromStr` (the spellings plus
/// aliases; anything else is an [`crate::Error::UnknownName`] listing `NAMES`), `Display`
/// (the spelling) and serde through them.
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

        crate::names::serde_via_str!($t);
    };
}
pub(crate) use named_enum;
