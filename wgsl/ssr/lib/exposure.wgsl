// Shared by exposure_partial and exposure_final: how two partials of the exposure statistic
// combine. A partial is 4 vec4: (sum ln d).rgb and count.rgb of the colour, then of the
// shadow; the w of the first three hold the colour's max of d.r, d.g, d.b (the output
// ceiling's m). Sums and counts add up, the maxes combine by max.

fn sum_max(a: vec4<f32>, b: vec4<f32>) -> vec4<f32> {
    return vec4<f32>(a.xyz + b.xyz, max(a.w, b.w));
}

fn combine(a: array<vec4<f32>, 4>, b: array<vec4<f32>, 4>) -> array<vec4<f32>, 4> {
    return array<vec4<f32>, 4>(sum_max(a[0], b[0]), sum_max(a[1], b[1]), sum_max(a[2], b[2]), a[3] + b[3]);
}
