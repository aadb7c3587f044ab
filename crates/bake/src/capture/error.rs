//! Errors of capture loading. Every message names the file it is about and, where there is
//! one, the JSON field (`frames[3].transform_matrix`) or the line of a mesh file.

use std::path::PathBuf;

/// Why a capture folder could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    /// A file could not be opened or read.
    #[error("{path}: cannot read: {source}", path = .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        #[source]
        source: std::io::Error,
    },
    /// A transforms file is not valid JSON.
    #[error("{path}:{line}:{column}: malformed JSON: {message}", path = .path.display())]
    Json {
        /// The transforms file.
        path: PathBuf,
        /// 1-based line of the syntax error.
        line: usize,
        /// 1-based column of the syntax error.
        column: usize,
        /// What the parser said.
        message: String,
    },
    /// A field of a transforms file is missing, has the wrong type or an invalid value.
    #[error("{path}: {field}: {message}", path = .path.display())]
    Field {
        /// The transforms file.
        path: PathBuf,
        /// The JSON path of the field, e.g. `frames[3].transform_matrix`.
        field: String,
        /// What is wrong with it.
        message: String,
    },
    /// The folder holds neither `transforms.json`, `transforms_train.json` nor a COLMAP model.
    #[error("{dir}: no transforms.json, transforms_train.json or COLMAP model (sparse/0/ or sparse/ with cameras and images .bin or .txt) in the capture folder", dir = .dir.display())]
    NoTransforms {
        /// The capture folder.
        dir: PathBuf,
    },
    /// A transforms file (or the training split drawn from it) has no frames.
    #[error("{path}: frames: {message}", path = .path.display())]
    NoFrames {
        /// The transforms file.
        path: PathBuf,
        /// Details (empty list, or nothing left for training after the hold-out).
        message: String,
    },
    /// More frames than the configured limit; checked before any image is read.
    #[error("{path}: frames: {count} frames exceed the limit of {max}", path = .path.display())]
    TooManyFrames {
        /// The transforms file.
        path: PathBuf,
        /// Number of frames listed.
        count: usize,
        /// The limit.
        max: usize,
    },
    /// The image a frame names does not exist, as written or with an image extension added.
    #[error(
        "{path}: {field}: image {image} not found (also tried adding .png, .jpg, .jpeg, .exr and upper case)",
        path = .path.display(),
        image = .image.display()
    )]
    ImageNotFound {
        /// The transforms file.
        path: PathBuf,
        /// The field, e.g. `frames[3].file_path`.
        field: String,
        /// The path as resolved against the capture folder.
        image: PathBuf,
    },
    /// An image file could not be decoded.
    #[error("{path}: cannot decode image: {message}", path = .path.display())]
    ImageDecode {
        /// The image file.
        path: PathBuf,
        /// What the decoder said.
        message: String,
    },
    /// An image's size disagrees with the `w`/`h` intrinsics of its frame.
    #[error(
        "{image}: image is {width}x{height} but {path} {field} says {expected_width}x{expected_height}",
        image = .image.display(),
        path = .path.display()
    )]
    ImageSize {
        /// The image file.
        image: PathBuf,
        /// The transforms file.
        path: PathBuf,
        /// The frame's fields, e.g. `frames[3] w/h`.
        field: String,
        /// Decoded width.
        width: u32,
        /// Decoded height.
        height: u32,
        /// Width from the intrinsics.
        expected_width: u32,
        /// Height from the intrinsics.
        expected_height: u32,
    },
    /// An image (or the sum of all images) exceeds the configured limits; checked from the
    /// file header before the pixels are decoded.
    #[error("{path}: {message}", path = .path.display())]
    TooLarge {
        /// The image or transforms file.
        path: PathBuf,
        /// Which limit, and by how much.
        message: String,
    },
    /// No proxy mesh: no `mesh_path`, no override and none of the default names exist.
    #[error(
        "{dir}: no proxy mesh: set mesh_path in the transforms file, pass --mesh, or add one of mesh.glb, mesh.gltf, mesh.obj, mesh.ply",
        dir = .dir.display()
    )]
    NoMesh {
        /// The capture folder.
        dir: PathBuf,
    },
    /// A mesh file has an extension no loader handles.
    #[error("{path}: unsupported mesh format (expected .glb, .gltf, .obj or .ply)", path = .path.display())]
    MeshFormat {
        /// The mesh file.
        path: PathBuf,
    },
    /// An OBJ or PLY mesh is malformed.
    #[error("{path}: {location}: {message}", path = .path.display())]
    MeshParse {
        /// The mesh file.
        path: PathBuf,
        /// Where: `line 12` (text) or `element vertex[3]` (binary PLY body).
        location: String,
        /// What is wrong.
        message: String,
    },
    /// A glTF mesh could not be loaded.
    #[error("{path}: cannot load glTF mesh: {message}", path = .path.display())]
    Gltf {
        /// The mesh file.
        path: PathBuf,
        /// What the glTF loader said.
        message: String,
    },
    /// The mesh (or one of its primitives) has no texture coordinates.
    #[error("{path}: {what} has no texture coordinates (--uv keep); --uv auto generates an atlas", path = .path.display())]
    MeshNoUvs {
        /// The mesh file.
        path: PathBuf,
        /// Which part, e.g. `mesh` or `primitive 2`.
        what: String,
    },
    /// The mesh has no triangles.
    #[error("{path}: mesh has no triangles", path = .path.display())]
    MeshEmpty {
        /// The mesh file.
        path: PathBuf,
    },
    /// The mesh exceeds the configured triangle or file-size limit.
    #[error("{path}: {message}", path = .path.display())]
    MeshTooLarge {
        /// The mesh file.
        path: PathBuf,
        /// Which limit.
        message: String,
    },
    /// A COLMAP model file is malformed or uses an unsupported camera model.
    #[error("{path}: {location}: {message}", path = .path.display())]
    Colmap {
        /// The model file.
        path: PathBuf,
        /// Where: `camera 3`, `image 12`, `line 7` or `byte 1024`.
        location: String,
        /// What is wrong.
        message: String,
    },
    /// A frame's image or mask is unusable (missing, or of the wrong size), named with the
    /// frame it belongs to.
    #[error("{path}: {frame}: {message}", path = .path.display())]
    Frame {
        /// The file that lists the frame (transforms file or COLMAP images file).
        path: PathBuf,
        /// The frame: `frames[3]` or `image 12 (IMG_0012.JPG)`.
        frame: String,
        /// What is wrong, naming the image or mask file.
        message: String,
    },
    /// The proxy mesh does not line up with the photographs (see `capture::alignment`).
    #[error("{dir}: alignment check: {message}", dir = .dir.display())]
    Misaligned {
        /// The capture folder.
        dir: PathBuf,
        /// The figures, the likely cause and the worst frames.
        message: String,
    },
    /// A texture atlas could not be generated for the mesh.
    #[error("{path}: generating UVs: {message}", path = .path.display())]
    UvAtlas {
        /// The mesh file.
        path: PathBuf,
        /// What the unwrapper said.
        message: String,
    },
}

impl CaptureError {
    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        CaptureError::Io {
            path: path.into(),
            source,
        }
    }
}
