// ARKit weights shown on a VRM avatar that has no ARKit morph targets: its expression presets
// (the vowels aa, ih, ou, ee, oh; blinks; happy, sad), which every VRM carries.
import { MORPH_INDEX } from './arkit.js';

/**
 * Terms of the lip aperture, as vispeech.motion.arkit.lip_aperture sums them: jawOpen opens the
 * lips, mouthClose shuts them against the jaw, lowering or raising a lip opens them, rolling the
 * lips in or pressing them closes them.
 */
const APERTURE_TERMS = [
  ['jawOpen', 1.0], ['mouthClose', -1.0],
  ['mouthLowerDownLeft', 0.25], ['mouthLowerDownRight', 0.25],
  ['mouthUpperUpLeft', 0.15], ['mouthUpperUpRight', 0.15],
  ['mouthFunnel', 0.1], ['mouthRollLower', -0.5], ['mouthRollUpper', -0.3],
  ['mouthPressLeft', -0.1], ['mouthPressRight', -0.1],
].map(([name, weight]) => [MORPH_INDEX.get(name), weight]);

/** Lip aperture at or below which the lips are closed (vispeech.motion.arkit.LIP_CLOSED); they part fully at twice that. */
export const LIP_CLOSED = 0.05;
/** Lip aperture at which a VRM's open vowels show in full (aa at 1). */
export const FULL_APERTURE = 0.4;
/** Rounding (the larger of mouthFunnel and mouthPucker) and spreading (of mouthStretch and mouthSmile) at which they count in full. */
export const FULL_SHAPE = 0.5;

const clip = (x) => Math.min(1, Math.max(0, x));
const mean = (weights, name) => (weights[MORPH_INDEX.get(`${name}Left`)] + weights[MORPH_INDEX.get(`${name}Right`)]) / 2;
const at = (weights, name) => weights[MORPH_INDEX.get(name)];

/** Lip aperture (0..1) of `weights` (indexed like MORPH_NAMES), as vispeech.motion.arkit.lip_aperture. */
export function lipAperture(weights) {
  return clip(APERTURE_TERMS.reduce((sum, [k, w]) => sum + w * weights[k], 0));
}

/**
 * The VRM expression presets (0..1 each) that show ARKit `weights` (indexed like MORPH_NAMES).
 *
 * The mouth is a blend of the five vowels by how open (`o`: 0 at LIP_CLOSED, 1 at
 * FULL_APERTURE), rounded (`r`) and spread (`s`) the lips are: open and neither is aa, open and
 * spread ee, open and rounded oh, barely open and spread ih, barely open and rounded ou:
 * aa = o(1-r)(1-s), ee = o(1-r)s, oh = or, ih = p(1-o)(1-r)s, ou = p(1-o)r, never more than 1
 * together, where `p` is how far the lips are parted (0 at LIP_CLOSED, 1 at twice that). Closed
 * lips (/p b m/) show no vowel at all, whatever their rounding: the VRM's mouth is at rest. The eyelids blink as ARKit's do; happy follows the raised cheeks
 * (cheekSquint, twice over) and sad the frown (mouthFrown, twice over), so that the speech's
 * own smile at /i/ spreads the lips without making the face glad.
 */
export function vrmExpressions(weights) {
  const aperture = lipAperture(weights);
  const o = clip((aperture - LIP_CLOSED) / (FULL_APERTURE - LIP_CLOSED));
  const p = clip(aperture / LIP_CLOSED - 1);
  const r = clip(Math.max(at(weights, 'mouthFunnel'), at(weights, 'mouthPucker')) / FULL_SHAPE);
  const s = clip(Math.max(mean(weights, 'mouthStretch'), mean(weights, 'mouthSmile')) / FULL_SHAPE);
  return {
    aa: o * (1 - r) * (1 - s),
    ee: o * (1 - r) * s,
    oh: o * r,
    ih: p * (1 - o) * (1 - r) * s,
    ou: p * (1 - o) * r,
    blinkLeft: at(weights, 'eyeBlinkLeft'),
    blinkRight: at(weights, 'eyeBlinkRight'),
    happy: clip(2 * mean(weights, 'cheekSquint')),
    sad: clip(2 * mean(weights, 'mouthFrown')),
  };
}
