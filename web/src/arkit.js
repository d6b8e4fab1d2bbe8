// ARKit blend-shape names, vispeech's tongue channels, and matching of morph-target and channel
// names onto them.

/** The 52 ARKit face blend shapes (Apple's order; key by name, never by position). */
export const ARKIT_NAMES = [
  'eyeBlinkLeft', 'eyeLookDownLeft', 'eyeLookInLeft', 'eyeLookOutLeft', 'eyeLookUpLeft',
  'eyeSquintLeft', 'eyeWideLeft', 'eyeBlinkRight', 'eyeLookDownRight', 'eyeLookInRight',
  'eyeLookOutRight', 'eyeLookUpRight', 'eyeSquintRight', 'eyeWideRight',
  'jawForward', 'jawLeft', 'jawRight', 'jawOpen',
  'mouthClose', 'mouthFunnel', 'mouthPucker', 'mouthLeft', 'mouthRight',
  'mouthSmileLeft', 'mouthSmileRight', 'mouthFrownLeft', 'mouthFrownRight',
  'mouthDimpleLeft', 'mouthDimpleRight', 'mouthStretchLeft', 'mouthStretchRight',
  'mouthRollLower', 'mouthRollUpper', 'mouthShrugLower', 'mouthShrugUpper',
  'mouthPressLeft', 'mouthPressRight', 'mouthLowerDownLeft', 'mouthLowerDownRight',
  'mouthUpperUpLeft', 'mouthUpperUpRight',
  'browDownLeft', 'browDownRight', 'browInnerUp', 'browOuterUpLeft', 'browOuterUpRight',
  'cheekPuff', 'cheekSquintLeft', 'cheekSquintRight', 'noseSneerLeft', 'noseSneerRight',
  'tongueOut',
];

/**
 * Every channel a head's morph target can carry: the ARKit shapes and vispeech's tongue tip
 * raise, body raise and backing (vispeech.motion.arkit.MORPH_NAMES).
 */
export const MORPH_NAMES = [...ARKIT_NAMES, 'tongueTipUp', 'tongueBodyUp', 'tongueBack'];

/** Position of each name in MORPH_NAMES. */
export const MORPH_INDEX = new Map(MORPH_NAMES.map((name, i) => [name, i]));

const BY_KEY = new Map(MORPH_NAMES.map((name) => [name.toLowerCase(), name]));

/**
 * The name in MORPH_NAMES that a morph-target or channel name stands for, or null.
 *
 * Matching ignores case and anything up to the last dot (`blendShape1.jawOpen`), reads
 * `_L` / `_R` suffixes as Left / Right (`eyeBlink_L`), and maps one side of a shape ARKit
 * keeps whole (`browInnerUp_L`, `cheekPuffRight`) onto that shape.
 */
export function morphName(name) {
  const key = String(name).split('.').pop().trim().toLowerCase()
    .replace(/_l$/, 'left').replace(/_r$/, 'right');
  if (BY_KEY.has(key)) return BY_KEY.get(key);
  const half = key.match(/^(.+)(left|right)$/);
  return half && BY_KEY.has(half[1]) ? BY_KEY.get(half[1]) : null;
}
