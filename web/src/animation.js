// Animation tracks (frames x named channels at a frame rate) and the file formats vispeech
// writes: vispeech animation JSON, Live Link Face CSV and TalkingHead animation JSON.

/**
 * Animation curves sampled at `fps`: frame k holds the channel values at
 * `startTime + k / fps` seconds of the audio. Frames may be appended while streaming.
 */
export class Animation {
  constructor({ fps, channels, frames = [], startTime = 0, phones = null, complete = true }) {
    if (!(fps > 0)) throw new Error(`animation fps must be positive, got ${fps}`);
    this.fps = Number(fps);
    this.channels = channels.map(String);
    this.startTime = Number(startTime) || 0;
    this.phones = phones;
    this.complete = complete;
    this.frames = [];
    this.append(0, frames);
  }

  /** Number of frames received so far. */
  get length() {
    return this.frames.length;
  }

  /** Seconds (of the audio) at which the frames end: `startTime + length / fps`. */
  get endTime() {
    return this.startTime + this.frames.length / this.fps;
  }

  /** Store `frames` (rows of channel values) from frame `start` on. */
  append(start, frames) {
    for (let k = 0; k < frames.length; k++) {
      const row = frames[k];
      if (!row || row.length !== this.channels.length) {
        throw new Error(`frame ${start + k} has ${row ? row.length : 0} values for ${this.channels.length} channels`);
      }
      this.frames[start + k] = Float32Array.from(row, Number);
    }
  }

  /** Fractional frame position at `t` seconds, clamped to the frames there are. */
  position(t) {
    const last = this.frames.length - 1;
    return Math.min(Math.max((t - this.startTime) * this.fps, 0), Math.max(last, 0));
  }

  /** Channel values at `t` seconds, linearly interpolated between frames, into `out`. */
  sample(t, out = new Float32Array(this.channels.length)) {
    if (!this.frames.length) return out.fill(0);
    const p = this.position(t);
    const i = Math.floor(p);
    const a = this.frames[i] || this.frames[0];
    const b = this.frames[i + 1] || a;
    const w = p - i;
    for (let c = 0; c < out.length; c++) out[c] = a[c] + w * (b[c] - a[c]);
    return out;
  }

  /** The phone (`{symbol, start, end, word, ...}`) sounding at `t` seconds, or null. */
  phoneAt(t) {
    const phones = this.phones && this.phones.phones;
    if (!phones) return null;
    return phones.find((p) => p.start <= t && t < p.end) || null;
  }
}

/** Read an animation file's text: vispeech JSON, TalkingHead JSON or Live Link Face CSV. */
export function parseAnimation(text, name = 'animation') {
  const trimmed = text.replace(/^\uFEFF/, '').trim();
  if (trimmed.startsWith('{')) {
    let data;
    try {
      data = JSON.parse(trimmed);
    } catch (err) {
      throw new Error(`${name}: not valid JSON (${err.message})`);
    }
    return animationFromJson(data, name);
  }
  if (/^timecode\s*,/i.test(trimmed)) return fromLiveLinkCsv(trimmed, name);
  throw new Error(`${name}: not a vispeech JSON, TalkingHead JSON or Live Link CSV animation`);
}

/** An Animation from a parsed JSON object: vispeech animation JSON or TalkingHead JSON. */
export function animationFromJson(data, name = 'animation') {
  if (data && data.format === 'vispeech-animation') return fromVispeechJson(data, name);
  const anim = data && (data.anim || data);
  if (anim && Array.isArray(anim.dt) && anim.vs && typeof anim.vs === 'object') {
    return fromTalkingHead(anim, name);
  }
  throw new Error(`${name}: JSON is neither a vispeech animation nor a TalkingHead animation`);
}

function fromVispeechJson(data, name) {
  if (data.version !== 1) throw new Error(`${name}: unsupported vispeech animation version ${data.version}`);
  if (!Array.isArray(data.channels) || !Array.isArray(data.frames)) {
    throw new Error(`${name}: vispeech animation needs "channels" and "frames" arrays`);
  }
  return new Animation({
    fps: data.fps,
    channels: data.channels,
    frames: data.frames,
    startTime: data.start_time || 0,
    phones: data.phones || null,
  });
}

// TalkingHead templates: segment i lasts dt[i] ms and ends with value vs[shape][i] (null keeps
// the previous value, [min, max] picks at random: we take the middle). Resampled at the
// median segment rate.
function fromTalkingHead(anim, name) {
  const dt = anim.dt.map(Number);
  if (!dt.length || dt.some((d) => !(d > 0))) throw new Error(`${name}: TalkingHead "dt" must hold positive durations (ms)`);
  const channels = Object.keys(anim.vs);
  const ends = [];
  dt.reduce((t, d) => (ends.push(t + d / 1000), t + d / 1000), 0);
  const curves = channels.map((ch) => {
    const values = anim.vs[ch];
    if (!Array.isArray(values)) throw new Error(`${name}: TalkingHead value list for ${ch} is not an array`);
    const keys = [0];
    let last = 0;
    for (let i = 0; i < ends.length; i++) {
      let v = values[i];
      if (Array.isArray(v)) v = (Number(v[0]) + Number(v[v.length - 1])) / 2;
      if (v !== null && v !== undefined) last = Number(v);
      if (i === 0) keys[0] = last;
      keys.push(last);
    }
    return keys;
  });
  const times = [0, ...ends];
  const sorted = [...dt].sort((a, b) => a - b);
  const fps = roundRate(1000 / sorted[Math.floor(sorted.length / 2)]);
  return new Animation({ fps, channels, frames: resample(times, curves, fps) });
}

/** Header names of Live Link Face CSV columns that are not blend shapes. */
const LIVE_LINK_META = new Set(['timecode', 'blendshapecount']);

/**
 * Read a Live Link Face CSV (`Timecode,BlendshapeCount,EyeBlinkLeft,...`). The timecode
 * `HH:MM:SS:FF.fff` counts frames at `timecodeFps` (60 in Live Link Face); times are
 * taken relative to the first row.
 */
export function fromLiveLinkCsv(text, name = 'animation', timecodeFps = 60) {
  const lines = text.split(/\r?\n/).filter((line) => line.trim());
  const header = lines[0].split(',').map((s) => s.trim());
  const keep = header.map((h, i) => (LIVE_LINK_META.has(h.toLowerCase()) ? -1 : i)).filter((i) => i >= 0);
  const tcColumn = header.findIndex((h) => h.toLowerCase() === 'timecode');
  const times = [];
  const rows = [];
  for (let r = 1; r < lines.length; r++) {
    const cells = lines[r].split(',');
    if (cells.length !== header.length) throw new Error(`${name}: row ${r + 1} has ${cells.length} fields, header has ${header.length}`);
    times.push(parseTimecode(cells[tcColumn], timecodeFps, `${name} row ${r + 1}`));
    rows.push(keep.map((i) => Number(cells[i])));
  }
  if (!rows.length) throw new Error(`${name}: Live Link CSV has no rows`);
  const t0 = times[0];
  const rel = times.map((t) => t - t0);
  const steps = rel.slice(1).map((t, i) => t - rel[i]).sort((a, b) => a - b);
  const step = steps.length ? steps[Math.floor(steps.length / 2)] : 1 / timecodeFps;
  if (!(step > 0)) throw new Error(`${name}: Live Link CSV timecodes do not increase`);
  const channels = keep.map((i) => header[i]);
  const curves = channels.map((_, c) => rows.map((row) => row[c]));
  const fps = roundRate(1 / step);
  return new Animation({ fps, channels, frames: resample(rel, curves, fps) });
}

function parseTimecode(tc, fps, where) {
  const m = /^\s*(\d+):(\d+):(\d+)[:;.](\d+(?:\.\d+)?)\s*$/.exec(tc || '');
  if (!m) throw new Error(`${where}: bad timecode ${JSON.stringify(tc)} (want HH:MM:SS:FF.fff)`);
  return Number(m[1]) * 3600 + Number(m[2]) * 60 + Number(m[3]) + Number(m[4]) / fps;
}

// A frame rate measured from rounded times, snapped to a whole number when that close.
function roundRate(fps) {
  return Math.abs(fps - Math.round(fps)) < 1e-3 ? Math.round(fps) : fps;
}

// Linear resampling of key curves (values at increasing `times`, seconds) onto frames at `fps`.
function resample(times, curves, fps) {
  const n = Math.max(1, Math.round(times[times.length - 1] * fps) + 1);
  const frames = [];
  let j = 0;
  for (let k = 0; k < n; k++) {
    const t = k / fps;
    while (j < times.length - 2 && times[j + 1] <= t) j++;
    const span = times[j + 1] - times[j];
    const w = span > 0 ? Math.min(Math.max((t - times[j]) / span, 0), 1) : 0;
    frames.push(curves.map((v) => (v.length > 1 ? v[j] + w * (v[j + 1] - v[j]) : v[0])));
  }
  return frames;
}
