//! One module per subcommand.

pub mod bench;
pub mod bench_bake;
pub mod bench_tables;
pub mod inspect;
pub mod validate;

// render / eval (renderer engineer)
pub mod eval;
pub mod render;
