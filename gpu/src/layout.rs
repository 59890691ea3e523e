//! The layouts of the `#[repr(C)]` [`bytemuck::Pod`] structs that the crate uploads into WGSL
//! structs (uniforms, and storage arrays of structs), for the shader-validation test
//! (`gpu/tests/shaders_validate.rs`) to compare with naga's layout of the WGSL: a field
//! added, moved or resized on one side only fails the tests, not a user's run. Not API.

/// The size and field offsets of one Rust struct uploaded into a WGSL struct.
#[derive(Clone, Debug)]
pub struct PodLayout {
    /// The Rust struct, with its module path.
    pub rust: &'static str,
    /// The name of the WGSL struct it fills.
    pub wgsl: &'static str,
    /// Which shader (and variant) `source` is.
    pub shader: &'static str,
    /// The whole WGSL the crate compiles for that shader (preludes prepended).
    pub source: String,
    /// `size_of` the Rust struct.
    pub size: usize,
    /// Each WGSL member's name, with the byte offset in the Rust struct of what fills it
    /// (named after the WGSL member where the Rust field's name differs).
    pub fields: Vec<(&'static str, usize)>,
}

/// Every Rust struct the crate uploads into a WGSL struct, once per shader (and shader
/// variant) that declares it.
pub fn pod_layouts() -> Vec<PodLayout> {
    let mut all = crate::scale_pod_layouts();
    all.extend(crate::doppler::pod_layouts());
    all.extend(crate::tracking::pod_layouts());
    all.extend(crate::relativity::pod_layouts());
    all.extend(crate::tonemap::pod_layouts());
    all
}

/// `pod_layout!(Rust => "Wgsl", "shader", source, { field, field as "wgsl_name",
/// field as "wgsl_name" + 4, ... })`: the [`PodLayout`] of `Rust`, invoked where its private
/// fields are visible. A field without `as` has the same name in WGSL; `+ n` names a member
/// `n` bytes into a Rust field (a `[f32; 3]` spread over three WGSL scalars).
macro_rules! pod_layout {
    ($rust:ident => $wgsl:literal, $shader:expr, $source:expr,
     { $($field:ident $(as $name:literal $(+ $extra:literal)?)?),* $(,)? }) => {
        $crate::layout::PodLayout {
            rust: concat!(module_path!(), "::", stringify!($rust)),
            wgsl: $wgsl,
            shader: $shader,
            source: String::from($source),
            size: ::std::mem::size_of::<$rust>(),
            fields: vec![$((
                $crate::layout::pod_layout!(@name $field $(as $name)?),
                ::std::mem::offset_of!($rust, $field) $($(+ $extra)?)?,
            )),*],
        }
    };
    (@name $field:ident) => {
        stringify!($field)
    };
    (@name $field:ident as $name:literal) => {
        $name
    };
}
pub(crate) use pod_layout;
