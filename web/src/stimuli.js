// Stimuli page: tracks on a GLB head, several side by side, drawn frame by frame for
// `vispeech stimuli render --head` (vispeech.evaluation.stimuli.render_faces drives it in
// headless Chromium). No clock and no idle motion: a frame shows the tracks' values and nothing
// else, so the same tracks always give the same pictures.
//
//   await window.vispeechStimuli.load(url, channels, width, height, background)
//   window.vispeechStimuli.frames(rows)  // rows[k][slot][c]: slot's value of channels[slot][c]
//                                        // -> a PNG data URL per row, the slots left to right
import * as THREE from 'three';
import { clone } from 'three/examples/jsm/utils/SkeletonUtils.js';
import { MORPH_INDEX, MORPH_NAMES, morphName } from './arkit.js';
import { HeadScene, loadHead, portraitRenderer } from './avatar.js';
import { HEAD_CHANNELS, trackHeadPose } from './performer.js';

/** One head per slot in a scene of its own, drawn into its own viewport of one canvas. */
class Stimuli {
  constructor(gltf, channels, width, height, background) {
    this.width = width;
    this.height = height;
    this.slots = channels.map((names) => {
      const head = new HeadScene({ ...gltf, scene: clone(gltf.scene) });
      head.frame(width / height);
      const lower = names.map((c) => String(c).toLowerCase());
      return {
        head,
        morphs: names.map((c) => {
          const name = morphName(c);
          return name === null ? -1 : MORPH_INDEX.get(name);
        }),
        pose: HEAD_CHANNELS.map((c) => lower.indexOf(c)),
        breath: lower.indexOf('breath'),
        weights: new Float32Array(MORPH_NAMES.length),
      };
    });
    this.renderer = portraitRenderer(new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true }));
    this.renderer.setPixelRatio(1);
    this.renderer.setSize(width * channels.length, height, false);
    this.renderer.setClearColor(background);
    this.renderer.setScissorTest(true);
    document.body.appendChild(this.renderer.domElement);
  }

  /** Pose every slot from `row` (as the web app does, without its fades) and draw them. */
  draw(row) {
    this.slots.forEach((slot, i) => {
      const values = row[i];
      slot.weights.fill(0);
      slot.morphs.forEach((k, c) => {
        if (k >= 0) slot.weights[k] = Math.min(1, Math.max(0, values[c]));
      });
      slot.head.setWeights(slot.weights);
      slot.head.setHeadRotation(...trackHeadPose(values, slot.pose, slot.breath));
      this.renderer.setViewport(i * this.width, 0, this.width, this.height);
      this.renderer.setScissor(i * this.width, 0, this.width, this.height);
      this.renderer.render(slot.head.scene, slot.head.camera);
    });
    return this.renderer.domElement.toDataURL('image/png');
  }
}

let stimuli = null;

window.vispeechStimuli = {
  /** Load the head at `url` once per slot; `channels[slot]` names the values each row gives it. */
  async load(url, channels, width, height, background = '#3a3f46') {
    stimuli = new Stimuli(await loadHead(url), channels, width, height, background);
    return stimuli.slots.map((slot) => slot.head.headIndex.size);
  },
  frames(rows) {
    return rows.map((row) => stimuli.draw(row));
  },
};
