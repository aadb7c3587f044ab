fn main() {
    eprintln!("dnr: not yet implemented");
    std::process::exit(2);
}
