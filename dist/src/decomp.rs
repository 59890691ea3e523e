//! The k-d split of a volume over ranks and the visibility order of the pieces for a view.
//!
//! The tree is built top down from the compositing factors (`k_m` at the root, ..., `k_1`
//! at the bottom, so ranks that composite together in round 1 are siblings): each node cuts
//! its voxel range along its longest axis into `k` slabs of (nearly) equal voxel counts,
//! ranks being assigned contiguously (a node of `k_1 * ... * k_i` ranks holds a contiguous
//! rank range). Radix-k's round `i` then merges exactly the children of the nodes at that
//! level, which are contiguous in any visibility order of the tree, so the "over" operator
//! (associative, not commutative) composites them correctly.
//!
//! World boxes: voxel `i` sits at `origin + i * spacing` (voxel centres); a piece of voxels
//! `[a, b)` owns the world slab from the face between voxels `a - 1` and `a` to the face
//! between `b - 1` and `b`, the outer faces of the domain being infinite, so the pieces'
//! half-open boxes ([`ClipBox`]) tile all of space: every sample point belongs to exactly one
//! piece. Sampling near a face reads the neighbour's voxels (trilinear): a piece reads its
//! voxels and one more layer on each inner face ([`Piece::read_lo`], [`Piece::read_hi`]).

use blueshift_camera::ClipBox;
use glam::Vec3;

use crate::{Error, Result};

/// One rank's piece of the domain.
#[derive(Clone, Debug, PartialEq)]
pub struct Piece {
    /// The rank.
    pub rank: usize,
    /// First voxel (inclusive) per axis.
    pub lo: [usize; 3],
    /// Last voxel (exclusive) per axis.
    pub hi: [usize; 3],
    /// The half-open world box this piece renders (infinite on the domain's outer faces).
    pub clip: ClipBox,
}

impl Piece {
    /// First voxel this piece's samples read (one layer beyond inner faces).
    #[must_use]
    pub fn read_lo(&self) -> [usize; 3] {
        self.lo.map(|l| l.saturating_sub(1))
    }
    /// Last voxel (exclusive) this piece's samples read, given the grid's `dims`.
    #[must_use]
    pub fn read_hi(&self, dims: [usize; 3]) -> [usize; 3] {
        [0, 1, 2].map(|a| (self.hi[a] + 1).min(dims[a]))
    }
}

/// A view, for the visibility order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Viewpoint {
    /// Orthographic: every ray has this direction (from the eye into the scene).
    Direction(Vec3),
    /// Perspective: rays leave this point.
    Eye(Vec3),
}

impl Viewpoint {
    /// The viewpoint of a camera.
    #[must_use]
    pub fn of(camera: &blueshift_camera::Camera) -> Self {
        match camera.projection {
            blueshift_camera::Projection::Orthographic { .. } => {
                Viewpoint::Direction(camera.target - camera.eye)
            }
            blueshift_camera::Projection::Perspective { .. } => Viewpoint::Eye(camera.eye),
        }
    }
}

#[derive(Clone, Debug)]
enum Node {
    Leaf(usize),
    Split {
        axis: usize,
        /// World coordinates of the `k - 1` inner faces, increasing.
        faces: Vec<f32>,
        children: Vec<Node>,
    },
}

/// The k-d split of a grid of `dims` voxels over `factors.iter().product()` ranks.
#[derive(Clone, Debug)]
pub struct Decomposition {
    dims: [usize; 3],
    factors: Vec<usize>,
    pieces: Vec<Piece>,
    root: Node,
}

impl Decomposition {
    /// Splits a grid of `dims` voxels (voxel `i` at `origin + i * spacing`) with the
    /// compositing `factors` (bottom round first, as [`crate::Strategy::factors`] gives them).
    ///
    /// # Errors
    /// [`Error::Parameter`] when a factor is below 2 (a single rank has the factor list
    /// `[]`), or a node has fewer voxels along its longest axis than children.
    pub fn new(dims: [usize; 3], origin: Vec3, spacing: Vec3, factors: &[usize]) -> Result<Self> {
        if factors.iter().any(|&k| k < 2) {
            return Err(Error::parameter(format!(
                "decomposition: factors {factors:?} must all be at least 2"
            )));
        }
        if dims.contains(&0) {
            return Err(Error::parameter("decomposition: the grid is empty"));
        }
        let mut pieces = Vec::new();
        let face = |axis: usize, v: usize| origin[axis] + (v as f32 - 0.5) * spacing[axis];
        #[allow(clippy::too_many_arguments)]
        fn build(
            lo: [usize; 3],
            hi: [usize; 3],
            clip: ClipBox,
            rank0: usize,
            levels: &[usize],
            face: &dyn Fn(usize, usize) -> f32,
            pieces: &mut Vec<Piece>,
        ) -> Result<Node> {
            let Some((&k, rest)) = levels.split_last() else {
                pieces.push(Piece {
                    rank: rank0,
                    lo,
                    hi,
                    clip,
                });
                return Ok(Node::Leaf(rank0));
            };
            let ext = [0, 1, 2].map(|a| hi[a] - lo[a]);
            let axis = (0..3).fold(0, |b, a| if ext[a] > ext[b] { a } else { b });
            if ext[axis] < k {
                return Err(Error::parameter(format!(
                    "decomposition: {} voxels along the longest axis cannot be split {k} ways \
                     (too many ranks for a {}x{}x{} region)",
                    ext[axis], ext[0], ext[1], ext[2]
                )));
            }
            let below: usize = rest.iter().product();
            let cut = |j: usize| lo[axis] + ext[axis] * j / k;
            let mut faces = Vec::with_capacity(k - 1);
            let mut children = Vec::with_capacity(k);
            for j in 0..k {
                let (mut clo, mut chi) = (lo, hi);
                clo[axis] = cut(j);
                chi[axis] = cut(j + 1);
                let mut c = clip;
                if j > 0 {
                    c.lo[axis] = face(axis, clo[axis]);
                    faces.push(c.lo[axis]);
                }
                if j + 1 < k {
                    c.hi[axis] = face(axis, chi[axis]);
                }
                children.push(build(clo, chi, c, rank0 + j * below, rest, face, pieces)?);
            }
            Ok(Node::Split {
                axis,
                faces,
                children,
            })
        }
        // The root splits by the last (top) factor: `levels` is consumed from the end.
        let root = build([0; 3], dims, ClipBox::ALL, 0, factors, &face, &mut pieces)?;
        pieces.sort_by_key(|p| p.rank);
        Ok(Self {
            dims,
            factors: factors.to_vec(),
            pieces,
            root,
        })
    }

    /// The number of ranks.
    #[must_use]
    pub fn ranks(&self) -> usize {
        self.pieces.len()
    }

    /// The grid's size in voxels.
    #[must_use]
    pub fn dims(&self) -> [usize; 3] {
        self.dims
    }

    /// The compositing factors the tree was built for (bottom round first).
    #[must_use]
    pub fn factors(&self) -> &[usize] {
        &self.factors
    }

    /// Every rank's piece, in rank order.
    #[must_use]
    pub fn pieces(&self) -> &[Piece] {
        &self.pieces
    }

    /// The ranks front to back for `view`: along every ray, the pieces it crosses come in
    /// this order (pieces it misses contribute nothing wherever they are). At each node the
    /// children are ordered by the view: orthographic, along the direction's sign on the
    /// node's axis; perspective, by slab distance from the slab holding the eye.
    #[must_use]
    pub fn visibility_order(&self, view: Viewpoint) -> Vec<usize> {
        fn walk(node: &Node, view: Viewpoint, out: &mut Vec<usize>) {
            match node {
                Node::Leaf(r) => out.push(*r),
                Node::Split {
                    axis,
                    faces,
                    children,
                } => {
                    let k = children.len();
                    let order: Vec<usize> = match view {
                        Viewpoint::Direction(d) => {
                            if d[*axis] < 0.0 {
                                (0..k).rev().collect()
                            } else {
                                (0..k).collect()
                            }
                        }
                        Viewpoint::Eye(e) => {
                            // The slab holding the eye (half-open, as the boxes are).
                            let j = faces.partition_point(|&f| f <= e[*axis]);
                            let mut o: Vec<usize> = (0..k).collect();
                            o.sort_by_key(|&i| (i.abs_diff(j), i));
                            o
                        }
                    };
                    for i in order {
                        walk(&children[i], view, out);
                    }
                }
            }
        }
        let mut out = Vec::with_capacity(self.ranks());
        walk(&self.root, view, &mut out);
        out
    }
}
