//! `--preset auto`'s measurements on small generated captures: the view-dependence test,
//! the untouched-texel mask, channel stripping at export, and the bound on pruning's renders.

mod capture_common;

use capture_common::shaded_sphere_capture;
use dnr_bake::auto::{prune, touched_texels, view_dependence};
use dnr_bake::capture::Capture;
use dnr_bake::train::config::{Preset, TrainConfig, DEFAULT_SUPERSAMPLE};
use dnr_bake::train::views::{self, View};
use dnr_bake::train::Trainer;

fn views_of(specular: f32) -> (tempfile::TempDir, Capture, Vec<View>) {
    let dir = tempfile::tempdir().unwrap();
    shaded_sphere_capture(dir.path(), specular);
    let cap = Capture::load(dir.path(), &Default::default()).unwrap();
    let v = views::prepare(&cap.mesh, &cap.train, DEFAULT_SUPERSAMPLE);
    (dir, cap, v)
}

/// The view-dependence test on a diffuse sphere and on one with a Phong highlight.
fn measure_diffuse_and_glossy() -> (
    view_dependence::ViewDependence,
    view_dependence::ViewDependence,
) {
    let (_d, _c, diffuse) = views_of(0.0);
    let (_s, _c2, glossy) = views_of(0.6);
    (
        view_dependence::measure(&diffuse),
        view_dependence::measure(&glossy),
    )
}

#[test]
fn diffuse_scene_is_not_view_dependent_and_highlights_are() {
    let (d, g) = measure_diffuse_and_glossy();
    eprintln!("diffuse {d:?}\nglossy {g:?}");
    assert!(d.texels > 100 && g.texels > 100, "too few texels measured");
    assert!(
        !d.view_dependent,
        "diffuse sphere measured as view dependent: {d:?}"
    );
    assert!(g.view_dependent, "highlights not detected: {g:?}");
    // A clear margin on both sides of the threshold, not a coin flip.
    assert!(d.excess_explained < 0.5 * d.threshold, "{d:?}");
    assert!(g.excess_explained > 2.0 * g.threshold, "{g:?}");
}

#[test]
fn a_sharp_highlight_asks_for_degree_3_and_a_diffuse_scene_does_not() {
    // The degree-3 functions explain the narrow Phong lobe's residual after degree 2; on a
    // diffuse sphere they explain no more than chance.
    let (d, g) = measure_diffuse_and_glossy();
    assert!(
        d.excess_explained_degree3 < 0.25 * d.degree3_threshold,
        "{d:?}"
    );
    assert_eq!(g.degree, 3, "{g:?}");
    assert!(
        g.excess_explained_degree3 > 1.5 * g.degree3_threshold,
        "{g:?}"
    );
}

fn small_cfg() -> TrainConfig {
    TrainConfig {
        resolution: 64,
        levels: 3,
        widths: vec![4, 8],
        threads: 1,
        ..TrainConfig::preset(Preset::Balanced)
    }
}

#[test]
fn untouched_texels_stay_zero_through_training() {
    let (_d, _c, v) = views_of(0.3);
    let mut t = Trainer::new(small_cfg(), &v).unwrap();
    let touched = touched_texels(&t.pyr, &v);
    let zeroed = t.zero_untouched(&touched);
    // The sphere's uv chart covers the square, but the poles' rows and a seam are thin;
    // at least some texels of the finest level must be untouched for the test to mean much.
    let untouched0 = touched[0].iter().filter(|&&b| !b).count();
    assert!(zeroed > 0 && untouched0 > 0, "nothing untouched");
    for _ in 0..5 {
        t.step(&v).unwrap();
    }
    let c = t.pyr.channels;
    for (k, (l, tk)) in t.pyr.levels.iter().zip(&touched).enumerate() {
        for (i, (texel, &seen)) in l.data.chunks_exact(c).zip(tk).enumerate() {
            if !seen {
                assert!(
                    texel.iter().all(|&x| x == 0.0),
                    "level {k} texel {i} moved: {texel:?}"
                );
            }
        }
    }
    // And touched texels did learn.
    assert!(t.pyr.levels[0].data.iter().any(|&x| x != 0.0));
}

#[test]
fn stripping_zeroed_channels_renders_the_same() {
    let (_d, cap, v) = views_of(0.3);
    let mut t = Trainer::new(small_cfg(), &v).unwrap();
    for _ in 0..3 {
        t.step(&v).unwrap();
    }
    t.freeze_zero_channels(&[12, 14, 15]);
    t.step(&v).unwrap();
    let c = t.pyr.channels;
    assert!(t.pyr.levels.iter().all(|l| l
        .data
        .chunks_exact(c)
        .all(|x| x[12] == 0.0 && x[14] == 0.0 && x[15] == 0.0)));
    let net = t.export_net();
    let (pyr2, net2) = prune::strip_channels(&t.pyr, &net, &[12, 14, 15]);
    assert_eq!(pyr2.channels, 13);
    let render = |pyr: &dnr_runtime::texture::Pyramid, net: &dnr_bake::export::ExportNet| {
        let b = dnr_bake::export::build(
            &cap.mesh,
            pyr,
            t.sh_layer(),
            net,
            t.out_ch,
            t.cfg.supersample,
            dnr_format::model::DType::F32,
        )
        .unwrap();
        let asset = b.build().unwrap();
        let r = dnr_runtime::renderer::Renderer::from_asset(&asset).unwrap();
        let f = &cap.test[0];
        r.render(&f.camera, f.width(), f.height()).unwrap()
    };
    let max_diff = |a: &[f32], b: &[f32]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0f32, f32::max)
    };
    let a = render(&t.pyr, &net);
    let b = render(&pyr2, &net2);
    let max = max_diff(&a.data, &b.data);
    assert!(max < 1e-5, "stripped asset renders differently: {max}");
    // A channel that is not zero must not be stripped silently: its removal shows.
    let (pyr3, net3) = prune::strip_channels(&t.pyr, &net, &[13]);
    let c3 = render(&pyr3, &net3);
    let max3 = max_diff(&a.data, &c3.data);
    assert!(
        max3 > 1e-4,
        "dropping a live channel changed nothing ({max3})"
    );
}

#[test]
fn prunable_channels_spare_colour_and_sh_band() {
    assert_eq!(
        prune::prunable_channels(16, Some((2, 3))),
        vec![12, 13, 14, 15]
    );
    assert_eq!(prune::prunable_channels(6, None), vec![3, 4, 5]);
}

#[test]
fn pruning_tries_only_what_its_renders_afford_largest_savings_first() {
    let (_d, _cap, v) = views_of(0.3);
    let (fit, val) = (&v[1..], &v[..1]);
    let mut t = Trainer::new(small_cfg(), fit).unwrap();
    for _ in 0..3 {
        t.step(fit).unwrap();
    }
    let levels = t.pyr.levels.len();
    let candidates = levels + prune::prunable_channels(t.pyr.channels, t.sh_layer()).len();
    assert!(
        levels > 1 && candidates > 3,
        "the scenario needs several candidates"
    );
    // Without a known base, one render is the base and one is kept for the joint check.
    let p = prune::prune(&mut t, val, None, 0.05, 4).unwrap();
    let tried: Vec<&str> = p.trials.iter().map(|t| t.item.as_str()).collect();
    assert_eq!(tried, ["level 0", "level 1"], "finest levels first");
    assert_eq!(p.untried.len(), candidates - 2, "{:?}", p.untried);
    assert_eq!(p.renders_afforded, 4);
    // With the base known, no render for it; too few renders try nothing and change nothing
    // (the first pass may have removed some: count what is left).
    let left = |t: &Trainer| {
        let l = t.pyr.levels.len();
        usize::from(l > 1) * l
            + prune::prunable_channels(t.pyr.channels, t.sh_layer())
                .iter()
                .filter(|c| !t.zero_channels().contains(c))
                .count()
    };
    let before = t.pyr.clone();
    let p = prune::prune(&mut t, val, Some(20.0), 0.05, 1).unwrap();
    assert!(p.trials.is_empty() && p.levels.is_empty() && p.channels.is_empty());
    assert_eq!(p.untried.len(), left(&t));
    assert_eq!(t.pyr.levels.len(), before.levels.len());
    let p = prune::prune(&mut t, val, Some(20.0), 0.05, 3).unwrap();
    assert_eq!(p.trials.len(), 2);
}
