fn main() {
    println!("hslt {}", env!("CARGO_PKG_VERSION"));
}
