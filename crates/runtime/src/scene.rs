//! Triangle geometry to rasterise: primitives in their local (mesh) space with the world
//! matrix of the node that instances them.

use glam::{Mat4, Vec2, Vec3};

/// One drawable primitive: an indexed triangle list in local space.
#[derive(Clone, Debug, Default)]
pub struct Primitive {
    /// Vertex positions in the primitive's local space.
    pub positions: Vec<Vec3>,
    /// Texture coordinates (glTF convention: (0,0) is the top-left of the image).
    pub uvs: Vec<Vec2>,
    /// Triangles as vertex indices, three per triangle.
    pub indices: Vec<u32>,
    /// Local-to-world matrix of the node instancing this primitive.
    pub world: Mat4,
    /// glTF material index, if any (selects the neural texture and renderer).
    pub material: Option<u32>,
}

/// Everything the rasteriser draws.
#[derive(Clone, Debug, Default)]
pub struct Scene {
    /// The primitives, each drawn with its own world matrix.
    pub primitives: Vec<Primitive>,
}
