//! Developer probes: small measurements of one solver question each, run as
//! `tacrom probe NAME [ARGS...]` (`cargo run --release --bin tacrom -- probe ...`). Each
//! module's doc gives its arguments; each prints a table to standard output. They use
//! the plugin's public API only, and their numbers are quoted in `docs/solvers.md`.

pub mod configs;
pub mod contact_size;
pub mod decoder_thickness;
pub mod deep;
pub mod fine_press;
pub mod first_contact;
pub mod image_time;
pub mod mesh_press;
pub mod newton_profile;
pub mod overshoot;
pub mod poisson;
pub mod press_sweep;
pub mod reference_study;
pub mod ridge;
pub mod rom_profile;
pub mod rom_region;
pub mod small;

/// A probe: its name and its entry point (`args[0]` is the name).
type Probe = (&'static str, fn(Vec<String>));

const PROBES: &[Probe] = &[
    ("configs", configs::run),
    ("contact_size", contact_size::run),
    ("decoder_thickness", decoder_thickness::run),
    ("deep", deep::run),
    ("fine_press", fine_press::run),
    ("first_contact", first_contact::run),
    ("image_time", image_time::run),
    ("mesh_press", mesh_press::run),
    ("newton_profile", newton_profile::run),
    ("overshoot", overshoot::run),
    ("poisson", poisson::run),
    ("press_sweep", press_sweep::run),
    ("reference_study", reference_study::run),
    ("ridge", ridge::run),
    ("rom_profile", rom_profile::run),
    ("rom_region", rom_region::run),
    ("small", small::run),
];

/// The probes' names, for the command line.
pub const NAMES: [&str; 17] = [
    "configs",
    "contact_size",
    "decoder_thickness",
    "deep",
    "fine_press",
    "first_contact",
    "image_time",
    "mesh_press",
    "newton_profile",
    "overshoot",
    "poisson",
    "press_sweep",
    "reference_study",
    "ridge",
    "rom_profile",
    "rom_region",
    "small",
];

/// Runs the probe `name` with `args` (its own arguments, without the name).
pub fn run(name: &str, args: Vec<String>) {
    let probe = PROBES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, f)| *f)
        .unwrap_or_else(|| panic!("unknown probe '{name}'"));
    probe(std::iter::once(name.to_owned()).chain(args).collect());
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_probe_is_named_once() {
        let names: Vec<_> = super::PROBES.iter().map(|(n, _)| *n).collect();
        assert_eq!(names, super::NAMES);
    }
}
