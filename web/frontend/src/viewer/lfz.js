// The LFZ1 binary frame format (docs/web.md): "LFZ1", uint32 header length H (little-endian),
// H bytes of UTF-8 JSON (padded so 8 + H is a multiple of 4), then one float32 block per cloud,
// count × channels, row-major. Blocks are viewed in place (no copy) as Float32Arrays.

export class FrameFormatError extends Error {}

export function parseFrame(buffer) {
  if (!(buffer instanceof ArrayBuffer)) throw new FrameFormatError("expected an ArrayBuffer");
  if (buffer.byteLength < 8) throw new FrameFormatError(`frame too short: ${buffer.byteLength} bytes`);
  const view = new DataView(buffer);
  const magic = String.fromCharCode(view.getUint8(0), view.getUint8(1), view.getUint8(2), view.getUint8(3));
  if (magic !== "LFZ1") throw new FrameFormatError(`not an LFZ1 frame (magic ${JSON.stringify(magic)})`);
  const headerLength = view.getUint32(4, true);
  if (8 + headerLength > buffer.byteLength) {
    throw new FrameFormatError(`header of ${headerLength} bytes runs past the end (${buffer.byteLength} bytes)`);
  }
  const text = new TextDecoder().decode(new Uint8Array(buffer, 8, headerLength));
  let header;
  try {
    header = JSON.parse(text);
  } catch (exc) {
    // Python's json writes NaN / Infinity (KITTI DontCare boxes have NaN geometry): read them as null
    try {
      header = JSON.parse(text.replace(/(?<=[[,:]\s*)(?:-?Infinity|NaN)(?=\s*[,\]}])/g, "null"));
    } catch {
      throw new FrameFormatError(`header is not JSON: ${exc.message}`);
    }
  }
  const base = 8 + headerLength;
  const clouds = (header.clouds ?? []).map((cloud) => {
    const channels = cloud.channels ?? [];
    const count = cloud.count ?? 0;
    const start = base + (cloud.offset ?? 0);
    const length = count * channels.length;
    if (start + length * 4 > buffer.byteLength) {
      throw new FrameFormatError(`cloud ${cloud.name}: ${count} × ${channels.length} floats run past the end`);
    }
    // Float32Array needs a 4-aligned offset; the format guarantees it, a copy copes when it does not hold
    const data = start % 4 === 0 ? new Float32Array(buffer, start, length) : new Float32Array(buffer.slice(start, start + length * 4));
    const index = Object.fromEntries(channels.map((name, i) => [name, i]));
    return { name: cloud.name, count, channels, stride: channels.length, index, data };
  });
  return { header, clouds, boxes: header.boxes ?? {}, finding: header.finding ?? null, bytes: buffer.byteLength };
}
