// Turbo (Mikhailov, Google 2019), from its polynomial approximation, as a 256-entry RGB table, trimmed
// to the part that stays readable on the viewer's dark background.

const R = [0.13572138, 4.6153926, -42.66032258, 132.13108234, -152.94239396, 59.28637943];
const G = [0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604];
const B = [0.1066733, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973];

function poly(c, x) {
  return c[0] + x * (c[1] + x * (c[2] + x * (c[3] + x * (c[4] + x * c[5]))));
}

const clamp01 = (v) => Math.min(1, Math.max(0, v));

const turboAt = (x) => [poly(R, x), poly(G, x), poly(B, x)].map((c) => Math.round(clamp01(c) * 255));

// WCAG contrast of two sRGB colours (0-255): (L1 + 0.05) / (L2 + 0.05), L the relative luminance.
const linear = (c) => ((c /= 255) <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4);
const luminance = ([r, g, b]) => 0.2126 * linear(r) + 0.7152 * linear(g) + 0.0722 * linear(b);
export function contrast(a, b) {
  const [hi, lo] = [luminance(a), luminance(b)].sort((p, q) => q - p);
  return (hi + 0.05) / (lo + 0.05);
}

// The viewer's clear colour (0x101217) and the contrast every colour of the map keeps against it
// (3:1, WCAG's figure for graphics): turbo's two ends, dark blue and dark red, vanish into the
// background, so the map is turbo between its first and last colours that keep it (about 0.09-0.89).
export const BACKGROUND_RGB = [16, 18, 23];
export const MIN_CONTRAST = 3;
export const TURBO_SPAN = (() => {
  const visible = (x) => contrast(turboAt(x), BACKGROUND_RGB) >= MIN_CONTRAST;
  let lo = 0;
  let hi = 1;
  while (lo < 0.5 && !visible(lo)) lo += 1 / 1024;
  while (hi > 0.5 && !visible(hi)) hi -= 1 / 1024;
  return [lo, hi];
})();

export const TURBO = (() => {
  const table = new Uint8Array(256 * 3);
  const [lo, hi] = TURBO_SPAN;
  for (let i = 0; i < 256; i++) table.set(turboAt(lo + (hi - lo) * (i / 255)), i * 3);
  return table;
})();

export function turboCss(x) {
  const i = Math.round(clamp01(x) * 255) * 3;
  return `rgb(${TURBO[i]},${TURBO[i + 1]},${TURBO[i + 2]})`;
}

export function turboGradient(steps = 12) {
  const stops = [];
  for (let k = 0; k <= steps; k++) stops.push(`${turboCss(k / steps)} ${((k / steps) * 100).toFixed(1)}%`);
  return `linear-gradient(to right, ${stops.join(", ")})`;
}

// A class id → a position on turbo far from its neighbours' (golden-ratio steps).
export function categorical(id) {
  return (((Math.round(id) * 0.6180339887) % 1) + 1) % 1;
}
