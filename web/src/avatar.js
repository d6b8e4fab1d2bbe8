// Avatars that show ARKit weights: a three.js head loaded from a GLB whose morph targets carry
// ARKit names, or the built-in 2D face (window.VispeechFace2D from static/face2d.js).
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { MeshoptDecoder } from 'three/examples/jsm/libs/meshopt_decoder.module.js';
import { MORPH_NAMES, morphName } from './arkit.js';

/**
 * A GLB head in a three.js scene, without a canvas: every mesh primitive whose morph targets
 * match ARKit names (or vispeech's tongue channels) is driven; `weights` are indexed like
 * MORPH_NAMES. A camera frames the face and lights light it. Avatar3D draws one on a page;
 * the stimuli page (stimuli.js) draws several side by side.
 */
export class HeadScene {
  constructor(gltf) {
    this.credit = (gltf.asset && gltf.asset.copyright) || null;
    this.targets = MORPH_NAMES.map(() => []); // per channel name: [{mesh, index}]
    this.head = null; // the mesh whose influences `influence()` reports
    let best = -1;
    gltf.scene.updateMatrixWorld(true);
    gltf.scene.traverse((obj) => {
      if (obj.isMesh && obj.geometry.attributes._occlusion) occludeHighlights(obj.material);
      if (!obj.isMesh || !obj.morphTargetDictionary) return;
      let matched = 0;
      for (const [targetName, index] of Object.entries(obj.morphTargetDictionary)) {
        const name = morphName(targetName);
        if (name === null) continue;
        this.targets[MORPH_NAMES.indexOf(name)].push({ mesh: obj, index });
        matched++;
      }
      const score = matched * 1e7 + obj.geometry.attributes.position.count;
      if (matched && score > best) {
        best = score;
        this.head = obj;
      }
    });
    if (!this.head) throw new Error(`${gltf.parser.options.path || 'GLB'}: no morph targets with ARKit names`);
    this.headIndex = new Map();
    this.targets.forEach((list, k) => {
      const own = list.find((t) => t.mesh === this.head);
      if (own) this.headIndex.set(MORPH_NAMES[k], own.index);
    });

    // Frame the face: the largest driven mesh's box, looking down -Z at its front, close enough
    // that the mouth reads in a chat window.
    const box = new THREE.Box3().setFromObject(this.head);
    const size = box.getSize(new THREE.Vector3());
    const center = box.getCenter(new THREE.Vector3());
    this.target = new THREE.Vector3(center.x, center.y + 0.1 * size.y, box.min.z + 0.6 * size.z);
    this.lift = 0.05 * size.y;
    this.distance = 1.3 * size.y;

    // Turn the head about a point low in the neck.
    const pivot = new THREE.Vector3(center.x, box.min.y + 0.25 * size.y, center.z);
    this.neck = new THREE.Group();
    this.neck.position.copy(pivot);
    gltf.scene.position.sub(pivot);
    this.neck.add(gltf.scene);

    this.scene = new THREE.Scene();
    this.scene.add(this.neck);
    this.scene.add(...portraitLights());

    this.camera = new THREE.PerspectiveCamera(25, 1, 0.01 * size.y, 100 * size.y);
  }

  /** Aim the camera for a view `aspect` (width / height) wide, keeping the face in view. */
  frame(aspect) {
    this.camera.aspect = aspect;
    const d = this.distance * Math.max(1, 0.9 / aspect);
    this.camera.position.set(this.target.x, this.target.y + this.lift, this.target.z + d);
    this.camera.lookAt(this.target);
    this.camera.updateProjectionMatrix();
  }

  /** Set every driven morph target from `weights` (indexed like MORPH_NAMES, 0..1). */
  setWeights(weights) {
    for (let k = 0; k < weights.length; k++) {
      for (const { mesh, index } of this.targets[k]) mesh.morphTargetInfluences[index] = weights[k];
    }
  }

  /** Turn the head by small angles (radians) about the neck. */
  setHeadRotation(pitch, yaw, roll) {
    this.neck.rotation.set(pitch, yaw, roll, 'YXZ');
  }

  /** Current morph influence of ARKit channel `name` on the head mesh (0 when absent). */
  influence(name) {
    const index = this.headIndex.get(morphName(name));
    return index === undefined ? 0 : this.head.morphTargetInfluences[index];
  }
}

/**
 * Dim the highlights of `material` by its vertices' `_occlusion` (vispeech rig prepare writes it
 * inside the mouth): there are no shadows here, so without it the throat would shine like the lips.
 */
function occludeHighlights(material) {
  if (material.userData.occluded) return;
  material.userData.occluded = true;
  material.customProgramCacheKey = () => 'vispeech-occlusion';
  material.onBeforeCompile = (shader) => {
    shader.vertexShader = shader.vertexShader
      .replace('#include <common>', '#include <common>\nattribute float _occlusion;\nvarying float vOcclusion;')
      .replace('#include <begin_vertex>', '#include <begin_vertex>\nvOcclusion = _occlusion;');
    shader.fragmentShader = shader.fragmentShader
      .replace('#include <common>', '#include <common>\nvarying float vOcclusion;')
      .replace('#include <lights_fragment_end>', '#include <lights_fragment_end>\n'
        + 'reflectedLight.directSpecular *= vOcclusion;\nreflectedLight.indirectSpecular *= vOcclusion;');
  };
}

/**
 * A portrait's lights: a warm key light from the upper left, a cool fill from the right, a
 * rim light from behind that parts the hair from the background, and a dim sky over a warm
 * floor for the shadows.
 */
function portraitLights() {
  const light = (colour, intensity, x, y, z) => {
    const directional = new THREE.DirectionalLight(colour, intensity);
    directional.position.set(x, y, z);
    return directional;
  };
  return [
    new THREE.HemisphereLight(0xf4f1ee, 0x4a3a32, 1.0),
    light(0xfff0e2, 2.6, -0.55, 0.6, 1),
    light(0xdfe8ff, 0.7, 0.9, 0.05, 0.6),
    light(0xffffff, 1.6, 0.25, 0.7, -1),
  ];
}

/** Set up `renderer` to draw heads: sRGB output with filmic tone mapping (highlights roll off as a camera's do). */
export function portraitRenderer(renderer) {
  renderer.outputColorSpace = THREE.SRGBColorSpace;
  renderer.toneMapping = THREE.NeutralToneMapping;
  renderer.toneMappingExposure = 1.0;
  return renderer;
}

/** Load a GLB head (meshopt-compressed or not) from `url`; resolves to three.js's glTF result. */
export function loadHead(url) {
  const loader = new GLTFLoader();
  loader.setMeshoptDecoder(MeshoptDecoder);
  return loader.loadAsync(url);
}

/** A GLB head on a page: a HeadScene drawn on a canvas that fills `container`. */
export class Avatar3D extends HeadScene {
  /** Load the GLB at `url` into a canvas appended to `container`. */
  static async load(container, url) {
    return new Avatar3D(container, await loadHead(url));
  }

  constructor(container, gltf) {
    super(gltf);
    this.container = container;
    this.blinks = false;
    this.renderer = portraitRenderer(new THREE.WebGLRenderer({ antialias: true, alpha: true }));
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    this.canvas = this.renderer.domElement;
    container.appendChild(this.canvas);
    this.resize();
    new ResizeObserver(() => this.resize()).observe(container);
  }

  /** Fit the canvas to its container and keep the face in view at any aspect ratio. */
  resize() {
    const w = Math.max(1, this.container.clientWidth);
    const h = Math.max(1, this.container.clientHeight);
    this.renderer.setSize(w, h, false);
    this.frame(w / h);
  }

  render() {
    this.renderer.render(this.scene, this.camera);
  }
}

/** Load the 2D face script once; resolves to its window.VispeechFace2D namespace. */
function loadFace2D(src) {
  if (window.VispeechFace2D) return Promise.resolve(window.VispeechFace2D);
  return new Promise((resolve, reject) => {
    const script = document.createElement('script');
    script.src = src;
    script.onload = () => (window.VispeechFace2D ? resolve(window.VispeechFace2D)
      : reject(new Error(`${src} did not define window.VispeechFace2D`)));
    script.onerror = () => reject(new Error(`could not load the 2D face from ${src}`));
    document.head.appendChild(script);
  });
}

/** The built-in 2D face, used when no GLB head is configured. It blinks on its own. */
export class Face2DAvatar {
  static async load(container, src = 'static/face2d.js') {
    const { Face2D } = await loadFace2D(src);
    return new Face2DAvatar(container, Face2D);
  }

  constructor(container, Face2D) {
    this.container = container;
    this.credit = null;
    this.blinks = true;
    this.canvas = document.createElement('canvas');
    this.canvas.className = 'face2d';
    container.appendChild(this.canvas);
    this.face = new Face2D(this.canvas);
    this.values = {};
    new ResizeObserver(() => this.face.resize()).observe(container);
  }

  setWeights(weights) {
    const values = {};
    for (let k = 0; k < weights.length; k++) values[MORPH_NAMES[k]] = weights[k];
    this.values = values;
  }

  /** Sway the drawing a little, as the 3D head turns. */
  setHeadRotation(pitch, yaw, roll) {
    const side = this.canvas.clientHeight;
    this.canvas.style.transform = `translate(${(yaw * side * 0.4).toFixed(2)}px, ${(pitch * side * 0.4).toFixed(2)}px) rotate(${roll.toFixed(4)}rad)`;
  }

  influence(name) {
    return this.values[morphName(name)] || 0;
  }

  /** Draw; `idleSeconds` drives the face's own blinks. */
  render(idleSeconds) {
    this.face.setWeights(this.values, idleSeconds);
  }
}

/** A 3D head from `avatarUrl`, or the 2D face (script at `face2dSrc`) when it is null. */
export async function createAvatar(container, avatarUrl, face2dSrc) {
  if (avatarUrl) return Avatar3D.load(container, avatarUrl);
  return Face2DAvatar.load(container, face2dSrc);
}
