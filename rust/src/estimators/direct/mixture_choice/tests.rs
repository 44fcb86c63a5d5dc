use super::*;

#[test]
fn pixels_take_the_mixture_of_least_second_moment_over_their_neighbours_draws() {
    let image = Techniques::PRODUCT;
    let choices = Choices::new(image);
    let q = |t: &Techniques, p: [f64; 4]| -> f64 {
        let c = t.probabilities(true, false, true);
        c.iter().zip(&p).map(|(c, p)| c * p).sum()
    };
    // One draw: f² / (q_k p₀) for every choice, p₀ the image mixture's density.
    let pdfs = [0.2, 0.0, 3.0, 0.5];
    let mut m = DrawMoments::default();
    m.add(&choices, 2.0, pdfs, q(&image, pdfs));
    m.add(&choices, 0.0, pdfs, q(&image, pdfs));
    assert_eq!(m.draws(), 2);
    for k in 0..CHOICES {
        let t = if k == 0 { image } else { CANDIDATES[k - 1] };
        let expected = 4.0 / (q(&t, pdfs) * q(&image, pdfs));
        assert!((m.sums[k] - expected).abs() <= 1e-12 * expected);
    }
    // Left columns: light where BSDF sampling goes and the product does not; right
    // columns: where the product goes. 8 draws per pixel.
    let (w, h) = (8, 5);
    let bsdf_light = [0.01, 0.0, 2.0, 0.1];
    let product_light = [4.0, 0.0, 0.3, 0.1];
    let moments: Vec<DrawMoments> = (0..w * h)
        .map(|i| {
            let p = if i % w < 4 { bsdf_light } else { product_light };
            let mut m = DrawMoments::default();
            for _ in 0..8 {
                m.add(&choices, 1.0, p, q(&image, p));
            }
            m
        })
        .collect();
    let chosen = PixelTechniques::measure(&moments, &choices, w, h);
    let bsdf_heaviest = CANDIDATES
        .iter()
        .fold(CANDIDATES[0], |a, b| if b.bsdf > a.bsdf { *b } else { a });
    assert_eq!(*chosen.get(2 * w), bsdf_heaviest);
    assert_eq!(chosen.get(2 * w + 7).product, 0.9);
    assert_eq!(chosen.counts().iter().sum::<u64>(), (w * h) as u64);
    // A pixel's own draws do not count: the same choices with pixel 2w's replaced.
    let mut changed = moments.clone();
    changed[2 * w] = moments[2 * w + 7];
    let again = PixelTechniques::measure(&changed, &choices, w, h);
    assert_eq!(again.get(2 * w), chosen.get(2 * w));
    // Too few draws in a window: the image's mixture.
    let sparse = vec![moments[0]; w * h];
    let few = PixelTechniques::measure(&sparse[..4], &choices, 2, 2);
    assert!((0..4).all(|i| *few.get(i) == image));
}
