//! A MuJoCo model (MJCF) generated from `[arm]`: each module a chain of rigid links joined by
//! elastic joints (a discretised rod), each actuator a spatial tendon through every link it
//! passes with a position servo on its length. Pure: a string, no I/O.
//!
//! The chain is laid out so that softarm's PCC kinematics (`softarm_kinematics::pcc::Arm`) is
//! what it does when every actuator holds its length:
//! - A module of length l is cut into n links of ℓ = l/n, its joints at s = (k + ½)ℓ: each link
//!   is tangent to the arc at its middle, so n equal bends of θ/n give the arc's end
//!   orientation exactly and its end position to O(θ²/n²). The first half link is the body
//!   before the module; the last link ends at the module's end, where the connector or the
//!   tool starts.
//! - Two hinges a joint (about the link's x and y; their order alternates from link to link so
//!   that the twist x-then-y makes cancels along a constant curvature), stiffness EI/ℓ; a soft
//!   module also a slide along the link, stiffness EA/ℓ.
//! - A tendon's sites at the module's base, at every joint and at its end, at its radius and
//!   angle (the module's rotation included) in every link's frame: the links are never turned
//!   about their axis, as PCC's module frames are not. A chord across a bend α is then
//!   ℓ − r sin α, PCC's ℓ − rα to third order.
//! - Every actuator preloaded against the structure (`PRELOAD_SHARE`), so that it holds its
//!   length shorter or longer, as PCC takes it, though a tendon only pulls and a chamber only
//!   pushes.
//! - A coupled tendon also crosses the connectors, which PCC's lengths leave out: its servo
//!   holds its length plus the connectors' (an affine bias, a `general` actuator).

use std::fmt::Write;

use softarm_arm::{Kind, Layout};
use softarm_sections::mujoco::Generated;

/// Simulation time step (s).
const TIMESTEP_S: f64 = 0.002;

/// The radius the links' inertia is taken at when a module's actuators are on its axis (m).
const MIN_LINK_RADIUS_M: f64 = 0.005;

/// How far the control range reaches past the stroke each way, as a share of the stroke: a
/// calibration's offsets and a scenario's creep move the lengths a little past it.
const CTRL_MARGIN: f64 = 0.25;

/// One module as built: its links and what they are made of.
struct Module {
    links: usize,
    /// Link length ℓ (m) as built.
    link_m: f64,
    /// Soft (a slide per link) or a fixed backbone.
    soft: bool,
    link_mass_kg: f64,
    /// Inertia about the link's centre: across and along its axis (kg·m²).
    inertia: [f64; 2],
    hinge_stiffness: f64,
    hinge_damping: f64,
    slide_stiffness: f64,
    /// Each slide's spring rest (m from the link as built).
    slide_rest_m: f64,
    slide_damping: f64,
}

/// The force every actuator holds at its commanded length (N), as a share of `max_force_n`.
/// PCC takes every actuator's length as held, shorter or longer; a tendon only pulls and a
/// chamber only pushes, so each is preloaded (a tendon pulls this much, a chamber pushes it,
/// against the structure) and holds its length either way within ± this over kp.
const PRELOAD_SHARE: f64 = 0.5;

fn preload_n(g: &Generated) -> f64 {
    PRELOAD_SHARE * g.max_force_n
}

/// A soft module's length as built (the middle of its actuators' range, where the model starts
/// straight) and its slides' spring rest length (m); a backbone's own length, twice. The rest
/// is longer than the middle by what the preloads it carries compress it by (tendons pull, a
/// chamber pushes): the module is straight at the middle of its range with every actuator at its
/// preload, as PCC has it there; away from the middle, the spring's change of force (EA/l per
/// metre) is what moves the lengths off the commanded ones, over kp.
fn lengths_m(layout: &Layout, g: &Generated, m: usize) -> (f64, f64) {
    let module = &layout.modules()[m];
    if let Some(b) = module.backbone_m {
        return (b, b);
    }
    let own = &layout.actuators()[module.actuators.clone()];
    let hi = own.iter().map(|a| a.max_m).fold(f64::MIN, f64::max);
    let lo = own.iter().map(|a| a.min_m).fold(f64::MAX, f64::min);
    let middle = (lo + hi) / 2.0;
    let net: f64 = layout
        .actuators()
        .iter()
        .enumerate()
        .filter(|&(i, _)| layout.passes(i, m))
        .map(|(_, a)| match a.kind {
            Kind::Tendon => 1.0,
            Kind::Chamber => -1.0,
        })
        .sum();
    (
        middle,
        middle + net * preload_n(g) * middle / g.soft_axial_n,
    )
}

/// Module `m`'s stiffness with its actuators holding their lengths: in bending (N·m/rad, the
/// module's EI/l and each actuator through it at radius r, kp r²/2 averaged over directions)
/// and along it (N/m, soft modules: EA/l and kp each).
fn held_stiffness(layout: &Layout, g: &Generated, m: usize, ei: f64, l: f64) -> (f64, f64) {
    let kp = g.actuator_stiffness_n_per_m;
    let through = || (0..layout.actuators().len()).filter(move |&i| layout.passes(i, m));
    let bend = ei / l
        + through()
            .map(|i| kp * layout.actuators()[i].radius_m.powi(2) / 2.0)
            .sum::<f64>();
    let axial = g.soft_axial_n / l + kp * through().count() as f64;
    (bend, axial)
}

/// Module `m`'s mass (kg): a soft module's or a backbone module's.
fn mass_of(layout: &Layout, g: &Generated, m: usize) -> f64 {
    match layout.modules()[m].backbone_m {
        None => g.module_mass_kg,
        Some(_) => g.backbone_module_mass_kg,
    }
}

/// Each module's links, stiffness and damping.
fn modules(layout: &Layout, g: &Generated) -> Vec<Module> {
    let count = layout.modules().len();
    let n = g.links_per_module;
    (0..count)
        .map(|m| {
            let (l, rest) = lengths_m(layout, g, m);
            let soft = layout.modules()[m].backbone_m.is_none();
            let ei = if soft {
                g.soft_bending_nm2
            } else {
                g.backbone_bending_nm2
            };
            let link_m = l / n as f64;
            let mass_kg = mass_of(layout, g, m);
            let link_mass_kg = mass_kg / n as f64;
            let radius = (0..layout.actuators().len())
                .filter(|&i| layout.passes(i, m))
                .map(|i| layout.actuators()[i].radius_m)
                .fold(MIN_LINK_RADIUS_M, f64::max);
            // A disk of the routing radius, as thick as the link.
            let across = link_mass_kg * (3.0 * radius * radius + link_m * link_m) / 12.0;
            let along = link_mass_kg * radius * radius / 2.0;
            // What the module carries beyond its end: the modules after it and the tool.
            let beyond =
                (m + 1..count).map(|k| mass_of(layout, g, k)).sum::<f64>() + g.tool_mass_kg;
            // The actuators through the module hold it: its first modes are theirs as much as
            // its own (bending: EI/l + kp Σr²/2 per rad; axial: EA/l + kp Σ1 per metre).
            let (bend_k, axial_k) = held_stiffness(layout, g, m, ei, l);
            let bend_w = (3.0 * bend_k / (l * l) / (0.24 * mass_kg + beyond)).sqrt();
            let axial_w = (axial_k / (mass_kg / 3.0 + beyond)).sqrt();
            let hinge_stiffness = ei / link_m;
            let slide_stiffness = g.soft_axial_n / link_m;
            // Joint damping c = 2ζ n k/ω₁ (k the module's held stiffness, ω₁ its first mode as a
            // cantilever of its own mass carrying what is beyond): n joints of c in series damp
            // that mode at the ratio ζ.
            let per_joint = 2.0 * g.damping_ratio * n as f64;
            Module {
                links: n,
                link_m,
                soft,
                link_mass_kg,
                inertia: [across, along],
                hinge_stiffness,
                hinge_damping: per_joint * bend_k / bend_w,
                slide_stiffness,
                slide_rest_m: (rest - l) / n as f64,
                slide_damping: per_joint * axial_k / axial_w,
            }
        })
        .collect()
}

/// The MJCF of `layout` made of `generated`'s values, under `gravity` (m/s², world frame).
///
/// The world is the arm's base frame: the base is fixed at the origin, the modules along +z
/// (standing) or −z (hanging, the base turned by diag(1, −1, −1)). Actuator i is the arm's
/// actuator i, named as it; its `ctrl` is the actuator's length (m), as
/// `softarm_arm::Actuator::length_of` gives it. The site `tip` is where PCC puts the end
/// effector, at the end of the tool.
pub fn mjcf(layout: &Layout, generated: &Generated, gravity: [f64; 3]) -> String {
    let modules = modules(layout, generated);
    let mut x = String::new();
    header(&mut x, gravity);
    let depth = bodies(&mut x, layout, &modules, generated);
    for level in (0..depth).rev() {
        line(&mut x, level + 2, "</body>");
    }
    x.push_str("  </worldbody>\n");
    tendons(&mut x, layout, &modules);
    actuators(&mut x, layout, generated);
    x.push_str("</mujoco>\n");
    x
}

fn header(x: &mut String, [gx, gy, gz]: [f64; 3]) {
    // implicitfast: the joints' damping and the servos' velocity terms implicit, which the
    // stiff chain of light links needs at 2 ms; no contacts (the arm never touches itself in
    // the arcs it is driven to, and contacts would cost the most of every step).
    let _ = write!(
        x,
        "<mujoco model=\"softarm generated from [arm]\">\n  \
         <compiler angle=\"radian\" autolimits=\"true\"/>\n  \
         <option timestep=\"{TIMESTEP_S}\" gravity=\"{gx} {gy} {gz}\" \
         integrator=\"implicitfast\"/>\n  \
         <default>\n    \
         <geom contype=\"0\" conaffinity=\"0\" rgba=\"0.6 0.6 0.65 1\"/>\n    \
         <site size=\"0.001\" rgba=\"0.8 0.3 0.2 1\"/>\n  \
         </default>\n  \
         <worldbody>\n"
    );
}

fn line(x: &mut String, indent: usize, text: &str) {
    for _ in 0..indent {
        x.push_str("  ");
    }
    x.push_str(text);
    x.push('\n');
}

/// Every module's links, nested, and the tool; how many bodies are left open.
fn bodies(x: &mut String, layout: &Layout, modules: &[Module], g: &Generated) -> usize {
    let quat = match layout.mount {
        softarm_arm::Mount::Standing => "1 0 0 0",
        // diag(1, −1, −1): half a turn about x.
        softarm_arm::Mount::Hanging => "0 1 0 0",
    };
    line(x, 2, &format!("<body name=\"base\" quat=\"{quat}\">"));
    let mut depth = 1;
    // Where the next module starts along the open body's z (m).
    let mut start_z = 0.0;
    for (m, module) in modules.iter().enumerate() {
        if m > 0 {
            start_z += layout.connector_m;
        }
        disk(x, depth + 2, layout, m, 0, start_z);
        for k in 0..module.links {
            let z = if k == 0 {
                start_z + module.link_m / 2.0
            } else {
                module.link_m
            };
            link(x, depth + 2, layout, module, m, k, z);
            depth += 1;
        }
        start_z = module.link_m / 2.0;
    }
    tool(x, depth + 2, layout, g, start_z);
    depth
}

/// Link `k` of module `m`, opened at `z` along its parent: its joints, its mass, its disk.
fn link(
    x: &mut String,
    indent: usize,
    layout: &Layout,
    module: &Module,
    m: usize,
    k: usize,
    z: f64,
) {
    let half = module.link_m / 2.0;
    line(
        x,
        indent,
        &format!("<body name=\"m{m}l{k}\" pos=\"0 0 {z}\">"),
    );
    let i = indent + 1;
    let hinge = |x: &mut String, axis: &str, name: &str| {
        line(
            x,
            i,
            &format!(
                "<joint name=\"m{m}l{k}{name}\" type=\"hinge\" axis=\"{axis}\" stiffness=\"{}\" \
                 damping=\"{}\"/>",
                module.hinge_stiffness, module.hinge_damping
            ),
        );
    };
    if k.is_multiple_of(2) {
        hinge(x, "1 0 0", "x");
        hinge(x, "0 1 0", "y");
    } else {
        hinge(x, "0 1 0", "y");
        hinge(x, "1 0 0", "x");
    }
    if module.soft {
        line(
            x,
            i,
            &format!(
                "<joint name=\"m{m}l{k}z\" type=\"slide\" axis=\"0 0 1\" stiffness=\"{}\" \
                 springref=\"{}\" damping=\"{}\"/>",
                module.slide_stiffness, module.slide_rest_m, module.slide_damping
            ),
        );
    }
    let [across, along] = module.inertia;
    line(
        x,
        i,
        &format!(
            "<inertial pos=\"0 0 {half}\" mass=\"{}\" diaginertia=\"{across} {across} {along}\"/>",
            module.link_mass_kg
        ),
    );
    let last = k + 1 == module.links;
    let end = if last { half } else { module.link_m };
    line(
        x,
        i,
        &format!(
            "<geom type=\"capsule\" fromto=\"0 0 0 0 0 {end}\" size=\"{}\"/>",
            half.min(0.004)
        ),
    );
    // The disk at the joint: a tendon's chord from the disk before is then ℓ − r sin α across
    // a bend α, PCC's ℓ − rα to third order, with no term in ℓα² (disks off the joints would
    // shorten every chord by ℓα²/8 under tension: a buckling the rod does not have).
    disk(x, i, layout, m, k + 1, 0.0);
    if last {
        disk(x, i, layout, m, k + 2, half);
    }
}

/// The sites of the actuators that pass module `m`, at disk `k` (`z` along the open body).
/// The module's base disk is the last one of the module before when no connector parts them:
/// a coupled tendon gets it once.
fn disk(x: &mut String, indent: usize, layout: &Layout, m: usize, k: usize, z: f64) {
    for (i, a) in layout.actuators().iter().enumerate() {
        if !layout.passes(i, m) || (k == 0 && shared_base(layout, i, m)) {
            continue;
        }
        let (s, c) = a.angle_rad.sin_cos();
        let (px, py) = (a.radius_m * c, a.radius_m * s);
        line(
            x,
            indent,
            &format!("<site name=\"{}\" pos=\"{px} {py} {z}\"/>", site(i, m, k)),
        );
    }
}

/// Whether actuator `i`'s site at module `m`'s base is its site at the end of module `m − 1`.
fn shared_base(layout: &Layout, i: usize, m: usize) -> bool {
    m > 0 && layout.connector_m == 0.0 && layout.passes(i, m - 1)
}

fn site(i: usize, m: usize, k: usize) -> String {
    format!("a{i}m{m}d{k}")
}

/// The tool: a rigid rod of the tool's mass from the last disk, ending in the site `tip`.
fn tool(x: &mut String, indent: usize, layout: &Layout, g: &Generated, z: f64) {
    let len = layout.tool_m;
    line(x, indent, &format!("<body name=\"tool\" pos=\"0 0 {z}\">"));
    if g.tool_mass_kg > 0.0 {
        let r = MIN_LINK_RADIUS_M;
        let across = g.tool_mass_kg * (3.0 * r * r + len * len) / 12.0;
        let along = g.tool_mass_kg * r * r / 2.0;
        line(
            x,
            indent + 1,
            &format!(
                "<inertial pos=\"0 0 {}\" mass=\"{}\" diaginertia=\"{across} {across} {along}\"/>",
                len / 2.0,
                g.tool_mass_kg
            ),
        );
    }
    if len > 0.0 {
        line(
            x,
            indent + 1,
            &format!("<geom type=\"capsule\" fromto=\"0 0 0 0 0 {len}\" size=\"0.002\"/>"),
        );
    }
    line(
        x,
        indent + 1,
        &format!("<site name=\"tip\" pos=\"0 0 {len}\" size=\"0.003\"/>"),
    );
    line(x, indent, "</body>");
}

/// Each actuator's spatial tendon: from the base of the first module it passes, through every
/// disk of every module it passes, to the end of its own.
fn tendons(x: &mut String, layout: &Layout, modules: &[Module]) {
    x.push_str("  <tendon>\n");
    for (i, _) in layout.actuators().iter().enumerate() {
        line(
            x,
            2,
            &format!("<spatial name=\"tendon{i}\" width=\"0.0005\">"),
        );
        for (m, module) in modules.iter().enumerate() {
            if !layout.passes(i, m) {
                continue;
            }
            for k in 0..=module.links + 1 {
                if k == 0 && shared_base(layout, i, m) {
                    continue;
                }
                line(x, 3, &format!("<site site=\"{}\"/>", site(i, m, k)));
            }
        }
        line(x, 2, "</spatial>");
    }
    x.push_str("  </tendon>\n");
}

/// The connectors actuator `i`'s tendon crosses (m): straight chords PCC's length leaves out.
fn connectors_crossed_m(layout: &Layout, i: usize) -> f64 {
    let passed = (0..layout.modules().len())
        .filter(|&m| layout.passes(i, m))
        .count();
    passed.saturating_sub(1) as f64 * layout.connector_m
}

/// A position servo on each tendon's length, in the arm's order: force
/// kp (ctrl + crossed ∓ preload/kp − length) − kv · speed, a tendon only pulling, a chamber
/// only pushing. kv = 2ζ√(kp · module mass): the servo's own mode damped as the joints are.
fn actuators(x: &mut String, layout: &Layout, g: &Generated) {
    x.push_str("  <actuator>\n");
    let kp = g.actuator_stiffness_n_per_m;
    let kv = 2.0 * g.damping_ratio * (kp * g.module_mass_kg).sqrt();
    let f = g.max_force_n;
    let stretch = preload_n(g) / kp;
    for (i, a) in layout.actuators().iter().enumerate() {
        let margin = CTRL_MARGIN * (a.max_m - a.min_m);
        let (lo, hi) = ((a.min_m - margin).max(0.0), a.max_m + margin);
        let (range, preload) = match a.kind {
            Kind::Tendon => (format!("{} 0", -f), -stretch),
            Kind::Chamber => (format!("0 {f}"), stretch),
        };
        let bias = kp * (connectors_crossed_m(layout, i) + preload);
        line(
            x,
            2,
            &format!(
                "<general name=\"{}\" tendon=\"tendon{i}\" ctrlrange=\"{lo} {hi}\" \
                 forcerange=\"{range}\" gainprm=\"{kp}\" biastype=\"affine\" \
                 biasprm=\"{bias} {} {}\"/>",
                escape(&a.name),
                -kp,
                -kv
            ),
        );
    }
    x.push_str("  </actuator>\n");
}

/// `text` safe inside an XML attribute.
fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c => out.push(c),
        }
    }
    out
}
