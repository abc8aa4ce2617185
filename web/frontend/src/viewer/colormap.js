// Turbo (Mikhailov, Google 2019), from its polynomial approximation, as a 256-entry RGB table.

const R = [0.13572138, 4.6153926, -42.66032258, 132.13108234, -152.94239396, 59.28637943];
const G = [0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604];
const B = [0.1066733, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973];

function poly(c, x) {
  return c[0] + x * (c[1] + x * (c[2] + x * (c[3] + x * (c[4] + x * c[5]))));
}

const clamp01 = (v) => Math.min(1, Math.max(0, v));

export const TURBO = (() => {
  const table = new Uint8Array(256 * 3);
  for (let i = 0; i < 256; i++) {
    const x = i / 255;
    table[i * 3] = Math.round(clamp01(poly(R, x)) * 255);
    table[i * 3 + 1] = Math.round(clamp01(poly(G, x)) * 255);
    table[i * 3 + 2] = Math.round(clamp01(poly(B, x)) * 255);
  }
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
