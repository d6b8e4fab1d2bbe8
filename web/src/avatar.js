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

    // Frame the face: the largest driven mesh's box, looking down -Z at its front.
    const box = new THREE.Box3().setFromObject(this.head);
    const size = box.getSize(new THREE.Vector3());
    const center = box.getCenter(new THREE.Vector3());
    this.target = new THREE.Vector3(center.x, center.y + 0.085 * size.y, box.min.z + 0.6 * size.z);
    this.lift = 0.055 * size.y;
    this.distance = 1.7 * size.y;

    // Turn the head about a point low in the neck.
    const pivot = new THREE.Vector3(center.x, box.min.y + 0.25 * size.y, center.z);
    this.neck = new THREE.Group();
    this.neck.position.copy(pivot);
    gltf.scene.position.sub(pivot);
    this.neck.add(gltf.scene);

    this.scene = new THREE.Scene();
    this.scene.add(this.neck);
    this.scene.add(new THREE.HemisphereLight(0xffffff, 0x3a3530, 1.6));
    const key = new THREE.DirectionalLight(0xffffff, 2.2);
    key.position.set(0.3, 0.5, 1);
    this.scene.add(key);

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
    this.renderer = new THREE.WebGLRenderer({ antialias: true, alpha: true });
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
