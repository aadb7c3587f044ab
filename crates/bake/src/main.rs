fn main() {
    eprintln!("dnr-bake: not yet implemented");
    std::process::exit(2);
}
