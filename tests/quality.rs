//! Grasp quality from contacts, each figure against a computation made in the test:
//! brute-force facet enumeration, the support function minimised over directions, and
//! closed forms.

use graspcell::quality::{
    self, epsilon::origin_depth, epsilon::OriginDepth, gws, wrench, Contact, QualityParams, Wrench,
};
use nalgebra::{Matrix3, Matrix6, Point3, Rotation3, SMatrix, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::f64::consts::{PI, TAU};

/// Contact at `point` on a sphere about the origin, normal toward the centre.
fn sphere_contact(point: Vector3<f64>) -> Contact {
    Contact {
        point: Point3::from(point),
        normal: -point.normalize(),
    }
}

fn params(mu: f64, edges: usize, r: f64) -> QualityParams {
    QualityParams {
        mu,
        cone_edges: edges,
        torque_scale_m: Some(r),
        centroid: Some(Point3::origin()),
    }
}

/// The test's own edge wrenches: f = n + mu (cos t1 + sin t2), [f; p x f / r] about
/// the origin, with the library's documented tangent choice.
fn own_wrenches(contacts: &[Contact], mu: f64, edges: usize, r: f64) -> Vec<Wrench> {
    let mut out = Vec::new();
    for c in contacts {
        let n = c.normal.normalize();
        let t1 = wrench::tangent_of(&n);
        let t2 = n.cross(&t1);
        let count = if mu == 0.0 { 1 } else { edges };
        for k in 0..count {
            let a = TAU * k as f64 / count as f64;
            let f = n + mu * (a.cos() * t1 + a.sin() * t2);
            let tau = c.point.coords.cross(&f) / r;
            out.push(Wrench::new(f.x, f.y, f.z, tau.x, tau.y, tau.z));
        }
    }
    out
}

/// Support function h(u) = max_i <u, w_i>.
fn support(w: &[Wrench], u: &Wrench) -> f64 {
    w.iter().map(|p| u.dot(p)).fold(f64::NEG_INFINITY, f64::max)
}

/// Epsilon by brute force over all 6-subsets: the facet hyperplanes of the hull are the
/// hyperplanes through 6 affinely independent wrenches with all wrenches on one side;
/// epsilon = max(0, min over them of the origin's signed distance inside).
fn brute_force_epsilon(w: &[Wrench]) -> f64 {
    let n = w.len();
    let tol = 1e-9;
    let mut nearest = f64::INFINITY;
    let mut facets = 0;
    let mut idx = [0usize, 1, 2, 3, 4, 5];
    loop {
        // Null vector (a, b) of the 6x7 rows [w_i, -1] by cofactors: a . w_i = b.
        let rows = SMatrix::<f64, 6, 7>::from_fn(|r, c| if c < 6 { w[idx[r]][c] } else { -1.0 });
        let mut x = [0.0; 7];
        for (k, xk) in x.iter_mut().enumerate() {
            let minor = Matrix6::from_fn(|r, c| rows[(r, if c < k { c } else { c + 1 })]);
            *xk = if k % 2 == 0 { 1.0 } else { -1.0 } * minor.determinant();
        }
        let a = Wrench::from_fn(|i, _| x[i]);
        let norm = a.norm();
        if norm > 1e-9 {
            let (a, b) = (a / norm, x[6] / norm);
            let (lo, hi) = w
                .iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
                    let d = a.dot(p) - b;
                    (lo.min(d), hi.max(d))
                });
            if hi <= tol {
                nearest = nearest.min(b);
                facets += 1;
            } else if lo >= -tol {
                nearest = nearest.min(-b);
                facets += 1;
            }
        }
        // Next 6-subset in lexicographic order.
        let mut i = 6;
        loop {
            if i == 0 {
                assert!(facets > 0, "no facet found");
                return nearest.max(0.0);
            }
            i -= 1;
            if idx[i] < n - 6 + i {
                idx[i] += 1;
                for j in i + 1..6 {
                    idx[j] = idx[j - 1] + 1;
                }
                break;
            }
        }
    }
}

/// Smoothed support function `(1/beta) log sum exp(beta <u, w_i>)` (>= h(u), within
/// `ln(n) / beta` of it) and its gradient.
fn smoothed_support(w: &[Wrench], u: &Wrench, beta: f64) -> (f64, Wrench) {
    let h = support(w, u);
    let mut sum = 0.0;
    let mut grad = Wrench::zeros();
    for p in w {
        let e = (beta * (u.dot(p) - h)).exp();
        sum += e;
        grad += p * e;
    }
    (h + sum.ln() / beta, grad / sum)
}

/// min over unit u of h(u) = max_i <u, w_i>, without any hull: the smallest of
/// `samples` random directions, then the best 16 refined by gradient descent on the
/// sphere of the smoothed support function with sharpness raised stage by stage
/// (continuation) up to an error bound `ln(n) / beta` of 1e-7. Returns the smallest
/// exact h(u) met; every one of them bounds epsilon from above.
fn support_minimum(w: &[Wrench], samples: usize, seed: u64) -> f64 {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut starts: Vec<(f64, Wrench)> = (0..samples)
        .map(|_| {
            let u = Wrench::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal)).normalize();
            (support(w, &u), u)
        })
        .collect();
    starts.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut best = starts[0].0;
    let beta_max = (w.len() as f64).ln() / 1e-7;
    for &(_, u0) in starts.iter().take(16) {
        let mut u = u0;
        let mut beta = 10.0;
        while beta < beta_max {
            beta = (beta * 3.0).min(beta_max);
            let mut step = 1.0 / beta;
            for _ in 0..200 {
                let (f, g) = smoothed_support(w, &u, beta);
                let tangent = g - u * g.dot(&u);
                if tangent.norm() < 1e-14 {
                    break;
                }
                // Backtracking (Armijo) along the tangent, retracted to the sphere.
                step *= 4.0;
                loop {
                    let v = (u - tangent * step).normalize();
                    if smoothed_support(w, &v, beta).0 <= f - 0.25 * step * tangent.norm_squared() {
                        u = v;
                        break;
                    }
                    step *= 0.5;
                    if step < 1e-16 {
                        break;
                    }
                }
                best = best.min(support(w, &u));
            }
        }
    }
    best
}

#[test]
fn three_contact_equilateral_matches_brute_force_and_support_function() {
    let r = 0.04;
    let contacts: Vec<Contact> = (0..3)
        .map(|k| {
            let a = TAU * k as f64 / 3.0;
            sphere_contact(Vector3::new(a.cos(), a.sin(), 0.0) * r)
        })
        .collect();
    let p = params(0.5, 8, r);
    let w = wrench::contact_wrenches(&contacts, &p).unwrap();
    let own = own_wrenches(&contacts, 0.5, 8, r);
    assert!(w.iter().zip(&own).all(|(a, b)| (a - b).norm() < 1e-12));

    let q = quality::evaluate(&contacts, &p).unwrap();
    let brute = brute_force_epsilon(&own);
    let sampled = support_minimum(&own, 20_000, 3);
    println!(
        "equilateral: epsilon {} brute {brute} sampled {sampled}",
        q.epsilon
    );
    assert!(q.force_closure && q.epsilon > 0.01);
    assert!((q.epsilon - brute).abs() < 1e-9, "{} vs {brute}", q.epsilon);
    // No direction has a support value below epsilon; the minimum is reached.
    assert!(sampled >= q.epsilon - 1e-12);
    assert!(
        sampled <= q.epsilon * (1.0 + 1e-4),
        "{sampled} vs {}",
        q.epsilon
    );
    assert!(q.volume > 0.0);
}

#[test]
fn six_axis_contacts_on_a_sphere_match_independent_computations() {
    let r = 0.05;
    let axes = [
        Vector3::x(),
        -Vector3::x(),
        Vector3::y(),
        -Vector3::y(),
        Vector3::z(),
        -Vector3::z(),
    ];
    let contacts: Vec<Contact> = axes.iter().map(|a| sphere_contact(a * r)).collect();
    // 4-edge pyramids: 24 wrenches, few enough to enumerate every 6-subset.
    let p4 = params(0.5, 4, r);
    let q4 = quality::evaluate(&contacts, &p4).unwrap();
    let brute = brute_force_epsilon(&own_wrenches(&contacts, 0.5, 4, r));
    println!(
        "six contacts, 4 edges: epsilon {} brute {brute}",
        q4.epsilon
    );
    assert!(q4.force_closure);
    assert!((q4.epsilon - brute).abs() < 1e-9);

    // 8-edge pyramids (48 wrenches): the support function minimised over directions.
    let p8 = params(0.5, 8, r);
    let q8 = quality::evaluate(&contacts, &p8).unwrap();
    let own = own_wrenches(&contacts, 0.5, 8, r);
    let sampled = support_minimum(&own, 20_000, 5);
    println!(
        "six contacts, 8 edges: epsilon {} sampled {sampled}",
        q8.epsilon
    );
    assert!(sampled >= q8.epsilon - 1e-12);
    assert!(
        sampled <= q8.epsilon * (1.0 + 1e-4),
        "{sampled} vs {}",
        q8.epsilon
    );
    // The 8-edge pyramid contains the 4-edge one.
    assert!(q8.epsilon >= q4.epsilon - 1e-12);
    // qhull agrees on epsilon.
    let hull = gws::hull_measures(&own).unwrap();
    assert!((hull.epsilon - q8.epsilon).abs() < 1e-9);
    assert!((hull.volume - q8.volume).abs() <= 1e-12 * hull.volume.max(1.0));
}

/// Closed form: a cube of half-side `a` about the origin, 4 frictionless contacts per
/// face at offset `s` along each in-face axis. The contact at `sigma e_i + t e_j` pushes
/// along `-sigma e_i` with moment `sigma t (e_i x e_j)`, so the wrenches are
/// `(+-e_i, +-(s/r) e_k)` for all i != k. Their support function is
/// `h(x, y) = max_{i != k} |x_i| + (s/r) |y_k|`; for s/r <= 1 its minimum over unit
/// directions is `(s/r)/sqrt(3)`, at x = 0, |y_k| = 1/sqrt(3).
#[test]
fn frictionless_cube_grasp_closed_form() {
    let (a, s, r) = (0.05, 0.02, 0.05);
    let mut contacts = Vec::new();
    for i in 0..3 {
        for sigma in [1.0, -1.0] {
            for j in (0..3).filter(|&j| j != i) {
                for t in [s, -s] {
                    let mut point = Vector3::zeros();
                    point[i] = sigma * a;
                    point[j] = t;
                    let mut normal = Vector3::zeros();
                    normal[i] = -sigma;
                    contacts.push(Contact {
                        point: Point3::from(point),
                        normal,
                    });
                }
            }
        }
    }
    let q = quality::evaluate(&contacts, &params(0.0, 8, r)).unwrap();
    let closed = (s / r) / 3f64.sqrt();
    println!("cube: epsilon {} closed form {closed}", q.epsilon);
    assert!(
        (q.epsilon - closed).abs() < 1e-9,
        "{} vs {closed}",
        q.epsilon
    );
    let sampled = support_minimum(&own_wrenches(&contacts, 0.0, 8, r), 20_000, 11);
    assert!(
        sampled >= closed - 1e-12 && sampled <= closed * (1.0 + 1e-5),
        "{sampled}"
    );
}

#[test]
fn frictionless_pairs_and_one_sided_grasps_have_no_force_closure() {
    let r = 0.05;
    // Two antipodal frictionless contacts: two wrenches (+-e_x, 0).
    let pair = [
        sphere_contact(Vector3::x() * r),
        sphere_contact(-Vector3::x() * r),
    ];
    let q = quality::evaluate(&pair, &params(0.0, 8, r)).unwrap();
    assert_eq!((q.epsilon, q.volume, q.force_closure), (0.0, 0.0, false));
    // Independently: they span one dimension, and h(e_y) = 0.
    let own = own_wrenches(&pair, 0.0, 8, r);
    let m = SMatrix::<f64, 6, 2>::from_columns(&[own[0], own[1]]);
    assert!(m.rank(1e-12) < 6);
    assert_eq!(
        support(&own, &Wrench::new(0.0, 1.0, 0.0, 0.0, 0.0, 0.0)),
        0.0
    );

    // Five contacts on the upper cap (within 50 degrees of the pole), mu 0.5: every
    // edge force points down (n_z <= -cos 50 < -mu sin 50), so h(+e_z) < 0.
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let cap: Vec<Contact> = (0..5)
        .map(|_| {
            let polar = rng.gen_range(0.0..50f64.to_radians());
            let az = rng.gen_range(0.0..TAU);
            sphere_contact(
                Vector3::new(polar.sin() * az.cos(), polar.sin() * az.sin(), polar.cos()) * r,
            )
        })
        .collect();
    let q = quality::evaluate(&cap, &params(0.5, 8, r)).unwrap();
    assert_eq!((q.epsilon, q.force_closure), (0.0, false));
    let own = own_wrenches(&cap, 0.5, 8, r);
    assert!(support(&own, &Wrench::new(0.0, 0.0, 1.0, 0.0, 0.0, 0.0)) < 0.0);
    assert!(q.volume > 0.0, "the one-sided hull still has volume");
}

#[test]
fn degenerate_sets_give_zero_without_panicking() {
    let r = 0.05;
    // Ten frictionless contacts around a circle in the xy plane: forces in xy, torques
    // about z only: the wrenches span 3 dimensions however many there are.
    let ring: Vec<Contact> = (0..10)
        .map(|k| {
            let a = TAU * k as f64 / 10.0 + 0.1;
            Contact {
                point: Point3::new(a.cos() * r, a.sin() * r, 0.0),
                normal: -Vector3::new((a + 0.3).cos(), (a + 0.3).sin(), 0.0),
            }
        })
        .collect();
    let own = own_wrenches(&ring, 0.0, 8, r);
    let rows = nalgebra::DMatrix::from_fn(own.len(), 6, |i, j| own[i][j]);
    assert_eq!(rows.rank(1e-12), 3);
    let q = quality::evaluate(&ring, &params(0.0, 8, r)).unwrap();
    assert_eq!((q.epsilon, q.volume, q.force_closure), (0.0, 0.0, false));
    // Fewer than 7 wrenches, and no contacts at all.
    let q = quality::evaluate(&ring[..6], &params(0.0, 8, r)).unwrap();
    assert_eq!((q.epsilon, q.volume), (0.0, 0.0));
    let q = quality::evaluate(&[], &QualityParams::default()).unwrap();
    assert_eq!((q.epsilon, q.volume, q.force_closure), (0.0, 0.0, false));
    // Coincident contacts: every wrench is one of 8 points on a plane.
    let same = vec![sphere_contact(Vector3::z() * r); 4];
    let q = quality::evaluate(&same, &params(0.5, 8, r)).unwrap();
    assert_eq!((q.epsilon, q.volume), (0.0, 0.0));
}

/// A random 3-6 contact set on a sphere of radius 5 cm, contacts spread around.
fn random_sphere_contacts(rng: &mut ChaCha8Rng, n: usize) -> Vec<Contact> {
    (0..n)
        .map(|_| {
            let d = Vector3::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal)).normalize();
            let tilt = Vector3::from_fn(|_, _| rng.gen_range(-0.2..0.2));
            Contact {
                point: Point3::from(d * 0.05),
                normal: -(d + tilt).normalize(),
            }
        })
        .collect()
}

#[test]
fn adding_a_contact_never_decreases_epsilon() {
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let p = params(0.5, 8, 0.05);
    let mut increased = 0;
    for _ in 0..150 {
        let n = rng.gen_range(3..=6);
        let mut contacts = random_sphere_contacts(&mut rng, n);
        let before = quality::evaluate(&contacts, &p).unwrap();
        contacts.extend(random_sphere_contacts(&mut rng, 1));
        let after = quality::evaluate(&contacts, &p).unwrap();
        assert!(
            after.epsilon >= before.epsilon - 1e-12,
            "{before:?} -> {after:?}"
        );
        assert!(after.volume >= before.volume * (1.0 - 1e-9));
        increased += usize::from(after.epsilon > before.epsilon);
    }
    assert!(increased > 30, "only {increased} sets gained epsilon");
}

#[test]
fn rigid_motions_leave_epsilon_unchanged() {
    let mut rng = ChaCha8Rng::seed_from_u64(23);
    for trial in 0..40 {
        let contacts = random_sphere_contacts(&mut rng, 3 + trial % 4);
        let p = params(0.5, 8, 0.05);
        let q = quality::evaluate(&contacts, &p).unwrap();
        let w = wrench::contact_wrenches(&contacts, &p).unwrap();

        // A random rotation R maps each wrench [f; tau] to [R f; R tau], an orthogonal
        // map of R^6: distances, hence epsilon and volume, are kept.
        let rot = Rotation3::from_scaled_axis(Vector3::from_fn(|_, _| rng.gen_range(-PI..PI)));
        let rotated: Vec<Wrench> = w
            .iter()
            .map(|x| {
                let f = rot * Vector3::new(x[0], x[1], x[2]);
                let t = rot * Vector3::new(x[3], x[4], x[5]);
                Wrench::new(f.x, f.y, f.z, t.x, t.y, t.z)
            })
            .collect();
        let eps_rotated = quality::epsilon_of_wrenches(&rotated);
        assert!(
            (eps_rotated - q.epsilon).abs() < 1e-9,
            "{eps_rotated} vs {}",
            q.epsilon
        );
        let hull = gws::hull_measures(&rotated).unwrap();
        assert!((hull.volume - q.volume).abs() <= 1e-9 * q.volume.max(1e-12));

        // Moving the contacts and the centroid together: the 24 rotations of the cube
        // (which map the pyramids' tangent frames onto each other for 8 edges) and a
        // translation.
        let shift = Vector3::from_fn(|_, _| rng.gen_range(-1.0..1.0));
        let m = cube_rotation(trial % 24);
        let moved: Vec<Contact> = contacts
            .iter()
            .map(|c| Contact {
                point: Point3::from(m * c.point.coords + shift),
                normal: m * c.normal,
            })
            .collect();
        let moved_params = QualityParams {
            centroid: Some(Point3::from(shift)),
            ..p
        };
        let q_moved = quality::evaluate(&moved, &moved_params).unwrap();
        assert!(
            (q_moved.epsilon - q.epsilon).abs() < 1e-9,
            "{q_moved:?} vs {q:?}"
        );
    }
}

/// The `k`-th (0..24) proper rotation of the cube: a signed permutation matrix.
fn cube_rotation(k: usize) -> Matrix3<f64> {
    let perms = [
        [0, 1, 2],
        [1, 2, 0],
        [2, 0, 1],
        [1, 0, 2],
        [0, 2, 1],
        [2, 1, 0],
    ];
    let perm = perms[k / 4];
    let signs = [1.0, -1.0][k % 2];
    let signs2 = [1.0, -1.0][(k / 2) % 2];
    let mut m = Matrix3::zeros();
    m[(0, perm[0])] = signs;
    m[(1, perm[1])] = signs2;
    m[(2, perm[2])] = 1.0;
    if m.determinant() < 0.0 {
        m[(2, perm[2])] = -1.0;
    }
    m
}

#[test]
fn cube_rotations_are_distinct_proper_rotations() {
    let all: Vec<Matrix3<f64>> = (0..24).map(cube_rotation).collect();
    for (i, a) in all.iter().enumerate() {
        assert!((a.determinant() - 1.0).abs() < 1e-12);
        assert!((a * a.transpose() - Matrix3::identity()).norm() < 1e-12);
        assert!(all[..i].iter().all(|b| (a - b).norm() > 0.5));
    }
}

#[test]
fn best_first_epsilon_matches_qhull_on_grasp_like_sets() {
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let mut inside = 0;
    for _ in 0..200 {
        let n = rng.gen_range(3..=6);
        let contacts = random_sphere_contacts(&mut rng, n);
        let w = wrench::contact_wrenches(&contacts, &params(0.5, 8, 0.05)).unwrap();
        let fast = match origin_depth(&w).unwrap() {
            OriginDepth::Inside { epsilon, .. } => {
                inside += 1;
                epsilon
            }
            _ => 0.0,
        };
        let reference = gws::hull_measures(&w).unwrap().epsilon;
        assert!(
            (fast - reference).abs() < 1e-9,
            "{fast} vs qhull {reference}"
        );
    }
    assert!(inside > 40, "only {inside} force-closure sets");
}

/// `cell quality --contacts FILE --json` on a file written here, and its errors.
#[test]
fn cli_reads_contacts_file() {
    let dir = graspcell::fsio::TempDir::new("quality-contacts").unwrap();
    let file = dir.join("contacts.json");
    let text = r#"{"mu": 0.5, "torque_scale": 0.04, "centroid": [0, 0, 0], "cone_edges": 8,
        "contacts": [
          {"point": [0.04, 0, 0], "normal": [-1, 0, 0]},
          {"point": [-0.02, 0.034641016151377546, 0], "normal": [0.5, -0.8660254037844386, 0]},
          {"point": [-0.02, -0.034641016151377546, 0], "normal": [0.5, 0.8660254037844386, 0]}]}"#;
    std::fs::write(&file, text).unwrap();
    let run = |path: &std::path::Path| {
        std::process::Command::new(env!("CARGO_BIN_EXE_cell"))
            .args(["quality", "--json", "--contacts"])
            .arg(path)
            .output()
            .unwrap()
    };
    let out = run(&file);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let eps = v["epsilon"].as_f64().unwrap();
    assert_eq!(v["force_closure"], serde_json::Value::Bool(true));
    assert!(v["volume"].as_f64().unwrap() > 0.0);
    // The same grasp as the equilateral test, by brute force here.
    let contacts: Vec<Contact> = (0..3)
        .map(|k| {
            let a = TAU * k as f64 / 3.0;
            sphere_contact(Vector3::new(a.cos(), a.sin(), 0.0) * 0.04)
        })
        .collect();
    let brute = brute_force_epsilon(&own_wrenches(&contacts, 0.5, 8, 0.04));
    assert!((eps - brute).abs() < 1e-9, "{eps} vs {brute}");

    // A zero normal is named by its contact index and the file.
    std::fs::write(
        &file,
        r#"{"contacts": [{"point": [0, 0, 0], "normal": [0, 0, 0]}]}"#,
    )
    .unwrap();
    let out = run(&file);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains("contacts.json") && err.contains("contact 0"),
        "{err}"
    );
    // An unknown field is rejected.
    std::fs::write(&file, r#"{"contacts": [], "friction": 1}"#).unwrap();
    let out = run(&file);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("friction"));
}
