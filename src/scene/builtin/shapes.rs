//! Geometry helpers for the built-in scenes: boxes, upright cards, discs and cylinders with
//! baked shading. All append to a [`Mesh`] in world space (metres, Y up), with texture
//! coordinates for every vertex.

use glam::{Vec2, Vec3};

use crate::scene::Mesh;

/// A face of an axis-aligned box, named by its outward normal.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Face {
    /// Facing +X.
    PosX,
    /// Facing -X.
    NegX,
    /// Facing +Y (the top).
    PosY,
    /// Facing -Y (the bottom).
    NegY,
    /// Facing +Z (towards a camera at larger Z looking down -Z).
    PosZ,
    /// Facing -Z.
    NegZ,
}

/// All six faces of a box.
pub(crate) const ALL_FACES: [Face; 6] = [
    Face::PosX,
    Face::NegX,
    Face::PosY,
    Face::NegY,
    Face::PosZ,
    Face::NegZ,
];

/// Appends the given faces of the axis-aligned box from `min` to `max`, each counter-clockwise
/// seen from outside, with UVs spanning the unit square.
pub(crate) fn push_box(mesh: &mut Mesh, min: Vec3, max: Vec3, faces: &[Face]) {
    let d = max - min;
    for &face in faces {
        // (corner, du, dv) with du x dv along the outward normal.
        let (p0, du, dv) = match face {
            Face::PosX => (
                Vec3::new(max.x, min.y, max.z),
                Vec3::new(0.0, 0.0, -d.z),
                Vec3::new(0.0, d.y, 0.0),
            ),
            Face::NegX => (min, Vec3::new(0.0, 0.0, d.z), Vec3::new(0.0, d.y, 0.0)),
            Face::PosY => (
                Vec3::new(min.x, max.y, max.z),
                Vec3::new(d.x, 0.0, 0.0),
                Vec3::new(0.0, 0.0, -d.z),
            ),
            Face::NegY => (min, Vec3::new(d.x, 0.0, 0.0), Vec3::new(0.0, 0.0, d.z)),
            Face::PosZ => (
                Vec3::new(min.x, min.y, max.z),
                Vec3::new(d.x, 0.0, 0.0),
                Vec3::new(0.0, d.y, 0.0),
            ),
            Face::NegZ => (
                Vec3::new(max.x, min.y, min.z),
                Vec3::new(-d.x, 0.0, 0.0),
                Vec3::new(0.0, d.y, 0.0),
            ),
        };
        mesh.push_quad(p0, du, dv);
    }
}

/// Appends an upright rectangle in the plane `z = top_left.z`, `width_m` wide along +X and
/// `height_m` tall, with its texture upright as seen from +Z (a camera looking down -Z).
pub(crate) fn push_card(mesh: &mut Mesh, top_left: Vec3, width_m: f32, height_m: f32) {
    mesh.push_quad(top_left, Vec3::X * width_m, Vec3::NEG_Y * height_m);
}

/// Appends a disc of radius `radius_m` around `centre` in the plane spanned by the unit
/// vectors `right` and `up` (front face towards `right x up`), as a fan of `segments`
/// triangles; UVs map the disc's bounding square to the unit square, upright.
pub(crate) fn push_disc(
    mesh: &mut Mesh,
    centre: Vec3,
    (right, up): (Vec3, Vec3),
    radius_m: f32,
    segments: u32,
) {
    let base = fill_uvs(mesh);
    mesh.positions.push(centre);
    mesh.uvs.push(Vec2::splat(0.5));
    for k in 0..segments {
        let (s, c) = (k as f32 * std::f32::consts::TAU / segments as f32).sin_cos();
        mesh.positions
            .push(centre + radius_m * (c * right + s * up));
        mesh.uvs.push(Vec2::new(0.5 + 0.5 * c, 0.5 - 0.5 * s));
    }
    for k in 0..segments {
        let next = (k + 1) % segments;
        mesh.indices.push([base, base + 1 + k, base + 1 + next]);
    }
}

/// Appends the convex polygon `corners` (in order, at least 3) as a fan of triangles from the
/// first corner, front face towards the side from which the corners run counter-clockwise; UVs
/// are all zero (for untextured materials).
pub(crate) fn push_convex_polygon(mesh: &mut Mesh, corners: &[Vec3]) {
    let base = fill_uvs(mesh);
    mesh.positions.extend_from_slice(corners);
    mesh.uvs.resize(mesh.positions.len(), Vec2::ZERO);
    for k in 1..corners.len().saturating_sub(1) as u32 {
        mesh.indices.push([base, base + k, base + k + 1]);
    }
}

/// Appends the side of a cylinder of radius `radius_m` from `a` to `b` with `sides` facets and
/// no caps. Its shading is baked into `u` for a ramp texture ([`super::textures::ramp_texture`],
/// dark at 0, highlight at 1): `u` is a diffuse-plus-specular term at each vertex normal for
/// unit light direction `light` and view direction `eye` (both pointing away from the
/// surface), so that interpolating `u` across facets shades the bar smoothly (Gouraud).
pub(crate) fn push_shaded_cylinder(
    mesh: &mut Mesh,
    (a, b): (Vec3, Vec3),
    radius_m: f32,
    sides: u32,
    (light, eye): (Vec3, Vec3),
) {
    let axis = (b - a).normalize();
    let e1 = axis.any_orthonormal_vector();
    let e2 = axis.cross(e1);
    let half = (light + eye).normalize();
    let base = fill_uvs(mesh);
    for k in 0..sides {
        let (s, c) = (k as f32 * std::f32::consts::TAU / sides as f32).sin_cos();
        let n = c * e1 + s * e2;
        let diffuse = n.dot(light).max(0.0);
        let specular = n.dot(half).max(0.0).powi(24);
        let u = (0.06 + 0.6 * diffuse + 0.5 * specular).clamp(0.0, 1.0);
        mesh.positions
            .extend_from_slice(&[a + radius_m * n, b + radius_m * n]);
        mesh.uvs
            .extend_from_slice(&[Vec2::new(u, 0.5), Vec2::new(u, 0.5)]);
    }
    for k in 0..sides {
        let next = (k + 1) % sides;
        let (a0, b0) = (base + 2 * k, base + 2 * k + 1);
        let (a1, b1) = (base + 2 * next, base + 2 * next + 1);
        mesh.indices.push([a0, a1, b1]);
        mesh.indices.push([a0, b1, b0]);
    }
}

/// Pads the mesh's UVs to its vertex count and returns the index of the next vertex.
fn fill_uvs(mesh: &mut Mesh) -> u32 {
    if mesh.uvs.len() < mesh.positions.len() {
        mesh.uvs.resize(mesh.positions.len(), Vec2::ZERO);
    }
    mesh.positions.len() as u32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sum over triangles of area-weighted normals dotted with (centroid - centre): positive
    /// when all faces point away from `centre`.
    fn outward_flux(mesh: &Mesh, centre: Vec3) -> Vec<f32> {
        mesh.indices
            .iter()
            .map(|t| {
                let [p0, p1, p2] = t.map(|i| mesh.positions[i as usize]);
                let n = (p1 - p0).cross(p2 - p0);
                n.dot((p0 + p1 + p2) / 3.0 - centre)
            })
            .collect()
    }

    #[test]
    fn box_faces_point_outward() {
        let mut m = Mesh::default();
        push_box(
            &mut m,
            Vec3::new(-1.0, 0.0, 2.0),
            Vec3::new(1.0, 3.0, 2.5),
            &ALL_FACES,
        );
        assert_eq!(m.triangle_count(), 12);
        assert_eq!(m.uvs.len(), m.positions.len());
        let centre = Vec3::new(0.0, 1.5, 2.25);
        assert!(outward_flux(&m, centre).iter().all(|&f| f > 0.0));
    }

    #[test]
    fn cylinder_facets_point_outward_and_shading_stays_in_the_ramp() {
        let mut m = Mesh::default();
        let (a, b) = (Vec3::ZERO, Vec3::Y);
        push_shaded_cylinder(&mut m, (a, b), 0.1, 12, (Vec3::X, Vec3::Z));
        assert_eq!(m.triangle_count(), 24);
        let centre = Vec3::new(0.0, 0.5, 0.0);
        assert!(outward_flux(&m, centre).iter().all(|&f| f > 0.0));
        assert!(m.uvs.iter().all(|uv| (0.0..=1.0).contains(&uv.x)));
    }

    #[test]
    fn disc_faces_right_cross_up() {
        let mut m = Mesh::default();
        push_disc(&mut m, Vec3::ZERO, (Vec3::X, Vec3::Y), 1.0, 8);
        assert_eq!(m.triangle_count(), 8);
        for t in &m.indices {
            let [p0, p1, p2] = t.map(|i| m.positions[i as usize]);
            assert!((p1 - p0).cross(p2 - p0).z > 0.0);
        }
    }
}
