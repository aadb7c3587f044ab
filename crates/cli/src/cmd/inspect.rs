//! `dnr inspect FILE [--json]`: what an asset holds and where its bytes go.

use std::collections::BTreeSet;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use dnr_format::asset::{bound_primitive_values, root_extension_value};
use dnr_format::exr_codec::{read_level_header, LevelCompression};
use dnr_format::model::{Extension, PrimitiveExtension};
use dnr_format::Container;
use serde::Serialize;

/// Arguments of `dnr inspect`.
#[derive(clap::Args)]
pub struct Args {
    /// The `.glb` or `.gltf` file.
    pub file: PathBuf,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
    /// Raise (or lower) a reader limit, NAME=VALUE; repeatable (e.g. max_texture_side=32768).
    /// Names: max_file_bytes, max_json_bytes, max_buffer_bytes, max_texture_side, max_levels,
    /// max_channels, max_total_texel_values, max_weight_elements, max_tensors, max_tensor_rank.
    #[arg(long = "limit", value_name = "NAME=VALUE")]
    pub limits: Vec<String>,
}

#[derive(Serialize)]
struct Summary {
    file: String,
    file_bytes: u64,
    generator: Option<String>,
    meshes: usize,
    primitives: usize,
    vertices: u64,
    triangles: u64,
    bindings: Vec<BindingSummary>,
    neural_textures: Vec<TextureSummary>,
    renderers: Vec<RendererSummary>,
    bytes: Bytes,
}

/// A mesh primitive's `EXT_deferred_neural_rendering` binding.
#[derive(Serialize)]
struct BindingSummary {
    mesh: usize,
    primitive: usize,
    /// The fallback material.
    material: Option<usize>,
    material_name: Option<String>,
    neural_texture: u32,
    renderer: u32,
    tex_coord: u32,
}

#[derive(Serialize)]
struct TextureSummary {
    channels: u32,
    wrap_s: String,
    wrap_t: String,
    view_dependence: Option<String>,
    levels: Vec<LevelSummary>,
}

#[derive(Serialize)]
struct LevelSummary {
    width: u32,
    height: u32,
    compression: String,
    bytes: u64,
}

#[derive(Serialize)]
struct RendererSummary {
    architecture: String,
    input_channels: u32,
    output_channels: u32,
    parameters: serde_json::Value,
    tensors: usize,
    parameter_count: u64,
    dtypes: Vec<String>,
    weight_bytes: u64,
}

#[derive(Serialize)]
struct Bytes {
    json: u64,
    mesh: u64,
    fallback_images: u64,
    texture_levels: u64,
    weights: u64,
    other_buffer_views: u64,
}

/// Prints the summary.
pub fn run(args: &Args) -> anyhow::Result<ExitCode> {
    let path = &args.file;
    let limits = super::validate::limits_from(&args.limits)?;
    let container = Container::read(path, &limits)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let summary = summarize(&container, path)
        .with_context(|| format!("cannot inspect {}", path.display()))?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print_text(&summary);
    }
    Ok(ExitCode::SUCCESS)
}

fn summarize(c: &Container, path: &std::path::Path) -> anyhow::Result<Summary> {
    let root = &c.root;
    let file_bytes = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
    let view_len = |v: u32| {
        root.buffer_views
            .get(v as usize)
            .map_or(0, |v| v.byte_length.0)
    };

    let mut counted: BTreeSet<u32> = BTreeSet::new();
    let mut mesh = 0u64;
    for a in &root.accessors {
        if let Some(v) = a.buffer_view {
            if counted.insert(v.value() as u32) {
                mesh += view_len(v.value() as u32);
            }
        }
    }
    let mut fallback_images = 0u64;
    for img in &root.images {
        if let Some(v) = img.buffer_view {
            if counted.insert(v.value() as u32) {
                fallback_images += view_len(v.value() as u32);
            }
        }
    }
    let (mut vertices, mut triangles, mut primitives) = (0u64, 0u64, 0usize);
    for m in &root.meshes {
        for p in &m.primitives {
            primitives += 1;
            if let Some(a) = p
                .attributes
                .get(&gltf_json::validation::Checked::Valid(
                    gltf_json::mesh::Semantic::Positions,
                ))
                .and_then(|i| root.accessors.get(i.value()))
            {
                vertices += a.count.0;
            }
            if let Some(a) = p.indices.and_then(|i| root.accessors.get(i.value())) {
                triangles += a.count.0 / 3;
            }
        }
    }

    let ext: Option<Extension> = match root_extension_value(root) {
        Some(v) => {
            Some(serde_json::from_value(v.clone()).context("the extension object does not parse")?)
        }
        None => None,
    };
    let mut textures = Vec::new();
    let mut renderers = Vec::new();
    let (mut level_bytes, mut weight_bytes_total) = (0u64, 0u64);
    if let Some(ext) = &ext {
        for t in &ext.neural_textures {
            let sampler = t.sampler.and_then(|s| root.samplers.get(s as usize));
            let wrap = |w: Option<
                &gltf_json::validation::Checked<gltf_json::texture::WrappingMode>,
            >| match w {
                Some(gltf_json::validation::Checked::Valid(m)) => format!("{m:?}"),
                Some(_) => "invalid".to_string(),
                None => "Repeat".to_string(),
            };
            let mut levels = Vec::new();
            for l in &t.levels {
                let bytes = view_len(l.buffer_view);
                if counted.insert(l.buffer_view) {
                    level_bytes += bytes;
                }
                let compression = c
                    .view_bytes(l.buffer_view)
                    .ok()
                    .and_then(|b| read_level_header(b).ok())
                    .map_or("unreadable".to_string(), |h| {
                        LevelCompression::from_exr(h.compression).map_or_else(
                            || format!("{:?} (not allowed)", h.compression),
                            |c| c.name().to_string(),
                        )
                    });
                levels.push(LevelSummary {
                    width: l.width,
                    height: l.height,
                    compression,
                    bytes,
                });
            }
            textures.push(TextureSummary {
                channels: t.channels,
                wrap_s: wrap(sampler.map(|s| &s.wrap_s)),
                wrap_t: wrap(sampler.map(|s| &s.wrap_t)),
                view_dependence: t.view_dependence.as_ref().map(|v| {
                    format!(
                        "{} degree {} on channels {}..{}",
                        v.basis,
                        v.degree,
                        v.first_channel,
                        u64::from(v.first_channel) + v.coefficient_count()
                    )
                }),
                levels,
            });
        }
        for r in &ext.renderers {
            let mut params = serde_json::Map::new();
            if let Some(h) = &r.hidden {
                params.insert("hidden".into(), serde_json::json!(h));
            }
            if let Some(w) = &r.widths {
                params.insert("widths".into(), serde_json::json!(w));
            }
            if let Some(d) = &r.decoder {
                params.insert("decoder".into(), serde_json::json!(d.as_str()));
            }
            if let Some(n) = &r.normalization {
                params.insert("normalization".into(), serde_json::json!(n.as_str()));
            }
            if let Some(s) = r.supersample {
                params.insert("supersample".into(), serde_json::json!(s));
            }
            let parameter_count = r.weights.iter().filter_map(|w| w.element_count()).sum();
            let weight_bytes: u64 = r.weights.iter().filter_map(|w| w.byte_length()).sum();
            for w in &r.weights {
                if counted.insert(w.buffer_view) {
                    weight_bytes_total += view_len(w.buffer_view);
                }
            }
            let dtypes: BTreeSet<String> = r.weights.iter().map(|w| w.dtype.to_string()).collect();
            renderers.push(RendererSummary {
                architecture: r.architecture.to_string(),
                input_channels: r.input_channels,
                output_channels: r.output_channels,
                parameters: serde_json::Value::Object(params),
                tensors: r.weights.len(),
                parameter_count,
                dtypes: dtypes.into_iter().collect(),
                weight_bytes,
            });
        }
    }
    let all_views: u64 = root.buffer_views.iter().map(|v| v.byte_length.0).sum();
    let counted_total: u64 = counted.iter().map(|&v| view_len(v)).sum();
    let json_bytes = serde_json::to_vec(root)
        .map(|v| v.len() as u64)
        .unwrap_or(0);
    let bindings = bound_primitive_values(root)
        .into_iter()
        .filter_map(|(mi, pi, v)| {
            let e: PrimitiveExtension = serde_json::from_value(v.clone()).ok()?;
            let material = root.meshes[mi].primitives[pi].material.map(|m| m.value());
            Some(BindingSummary {
                mesh: mi,
                primitive: pi,
                material,
                material_name: material
                    .and_then(|m| root.materials.get(m))
                    .and_then(|m| m.name.clone()),
                neural_texture: e.neural_texture,
                renderer: e.renderer,
                tex_coord: e.tex_coord,
            })
        })
        .collect();
    Ok(Summary {
        file: path.display().to_string(),
        file_bytes,
        generator: root.asset.generator.clone(),
        meshes: root.meshes.len(),
        primitives,
        vertices,
        triangles,
        bindings,
        neural_textures: textures,
        renderers,
        bytes: Bytes {
            json: json_bytes,
            mesh,
            fallback_images,
            texture_levels: level_bytes,
            weights: weight_bytes_total,
            other_buffer_views: all_views.saturating_sub(counted_total),
        },
    })
}

fn print_text(s: &Summary) {
    println!(
        "{} ({} bytes, generator {})",
        s.file,
        s.file_bytes,
        s.generator.as_deref().unwrap_or("-")
    );
    println!(
        "meshes: {} ({} primitives, {} vertices, {} triangles)",
        s.meshes, s.primitives, s.vertices, s.triangles
    );
    for b in &s.bindings {
        let fallback = match (b.material, b.material_name.as_deref()) {
            (Some(m), Some(name)) => format!("fallback material {m} `{name}`"),
            (Some(m), None) => format!("fallback material {m}"),
            (None, _) => "no fallback material".to_string(),
        };
        println!(
            "mesh {} primitive {}: neural texture {}, renderer {}, TEXCOORD_{} ({fallback})",
            b.mesh, b.primitive, b.neural_texture, b.renderer, b.tex_coord
        );
    }
    for (i, t) in s.neural_textures.iter().enumerate() {
        println!(
            "neural texture {i}: {} channels, {} levels, wrap {}/{}, view dependence: {}",
            t.channels,
            t.levels.len(),
            t.wrap_s,
            t.wrap_t,
            t.view_dependence.as_deref().unwrap_or("none")
        );
        for (li, l) in t.levels.iter().enumerate() {
            println!(
                "  level {li}: {}x{} {} ({} bytes)",
                l.width, l.height, l.compression, l.bytes
            );
        }
    }
    for (i, r) in s.renderers.iter().enumerate() {
        println!(
            "renderer {i}: {} {} -> {} channels {}, {} tensors, {} parameters ({}; {} bytes)",
            r.architecture,
            r.input_channels,
            r.output_channels,
            r.parameters,
            r.tensors,
            r.parameter_count,
            if r.dtypes.is_empty() {
                "-".to_string()
            } else {
                r.dtypes.join("/")
            },
            r.weight_bytes
        );
    }
    let b = &s.bytes;
    println!(
        "bytes: json {}, mesh {}, fallback images {}, texture levels {}, weights {}, other {}",
        b.json, b.mesh, b.fallback_images, b.texture_levels, b.weights, b.other_buffer_views
    );
}
