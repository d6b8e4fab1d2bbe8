// Avatars that show ARKit weights: a three.js head loaded from a GLB or VRM whose morph targets
// carry ARKit names, a VRM without them through its expression presets, or the built-in 2D face
// (window.VispeechFace2D from static/face2d.js).
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { MeshoptDecoder } from 'three/examples/jsm/libs/meshopt_decoder.module.js';
import { VRMLoaderPlugin, VRMUtils } from '@pixiv/three-vrm';
import { MORPH_NAMES, morphName } from './arkit.js';
import { vrmExpressions } from './expressions.js';

/**
 * A GLB or VRM head in a three.js scene, without a canvas. Every mesh primitive whose morph
 * targets match ARKit names (or vispeech's tongue channels) is driven; a VRM whose custom
 * expressions carry ARKit names has them driven instead ("perfect sync"), and a VRM with
 * neither shows the weights through its expression presets (expressions.js). `weights` are
 * indexed like MORPH_NAMES. A camera frames the face and lights light it. Avatar3D draws one
 * on a page; the stimuli page (stimuli.js) draws several side by side.
 */
export class HeadScene {
  constructor(gltf) {
    this.vrm = gltf.userData.vrm || null;
    if (this.vrm) VRMUtils.rotateVRM0(this.vrm); // VRM 0.x faces -Z, 1.0 and the camera's view +Z
    this.credit = this.vrm ? vrmCredit(this.vrm.meta) : (gltf.asset && gltf.asset.copyright) || null;
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
    this.headIndex = new Map();
    this.targets.forEach((list, k) => {
      const own = list.find((t) => t.mesh === this.head);
      if (own) this.headIndex.set(MORPH_NAMES[k], own.index);
    });
    this.expressions = this.head || !this.vrm ? null : vrmDrive(this.vrm.expressionManager);
    if (!this.head && !this.expressions) {
      throw new Error(`${gltf.parser.options.path || 'GLB'}: no morph targets with ARKit names`);
    }
    this.lastUpdate = null;

    // Frame the face (the largest driven mesh, or a VRM's head), looking down -Z at its front,
    // close enough that the mouth reads in a chat window: above the middle of a head mesh, which
    // reaches down the neck; at the nose of a skull (chin to crown), from further away.
    const { box, skull } = this.vrm ? vrmHeadBox(this.vrm) : { box: new THREE.Box3().setFromObject(this.head) };
    const size = box.getSize(new THREE.Vector3());
    const center = box.getCenter(new THREE.Vector3());
    const [aim, away] = skull ? [0.33, 2.2] : [0.6, 1.3];
    this.target = new THREE.Vector3(center.x, box.min.y + aim * size.y, box.min.z + 0.6 * size.z);
    this.lift = 0.05 * size.y;
    this.distance = away * size.y;

    // Turn the head about a point low in the neck (a VRM's own neck bone turns it instead).
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

  /**
   * Set every driven morph target (or a VRM's expressions) from `weights` (indexed like
   * MORPH_NAMES, 0..1); a VRM then updates its expressions, spring bones and constraints.
   */
  setWeights(weights) {
    if (this.expressions) this.expressions.set(weights);
    if (this.vrm) {
      const now = performance.now() / 1000;
      this.vrm.update(this.lastUpdate === null ? 0 : Math.min(now - this.lastUpdate, 0.1));
      this.lastUpdate = now;
    }
    for (let k = 0; k < weights.length; k++) {
      for (const { mesh, index } of this.targets[k]) mesh.morphTargetInfluences[index] = weights[k];
    }
  }

  /**
   * Turn the head by small angles (radians) about the neck: a VRM's neck bone (a VRM 0.x model's
   * bones face -Z, so pitch and roll turn the other way there), else the head's pivot.
   */
  setHeadRotation(pitch, yaw, roll) {
    const neck = this.vrm && this.vrm.humanoid.getNormalizedBoneNode('neck');
    if (!neck) {
      this.neck.rotation.set(pitch, yaw, roll, 'YXZ');
      return;
    }
    const sign = this.vrm.meta && this.vrm.meta.metaVersion === '0' ? -1 : 1;
    neck.rotation.set(sign * pitch, yaw, sign * roll, 'YXZ');
  }

  /** Current morph influence of ARKit channel `name` on the head mesh (0 when absent). */
  influence(name) {
    const index = this.headIndex.get(morphName(name));
    return index === undefined ? 0 : this.head.morphTargetInfluences[index];
  }

  /** Current weight of a VRM's expression `name` (`aa`, `blinkLeft`, ...); null when there is none. */
  expression(name) {
    return this.vrm ? this.vrm.expressionManager.getValue(name) : null;
  }

  /** How the weights are shown: 'morphs' (ARKit morph targets), 'arkit-expressions' or 'vrm-presets'. */
  get drive() {
    return this.expressions ? this.expressions.kind : 'morphs';
  }
}

/**
 * What drives a VRM that has no ARKit morph targets: its custom expressions named after ARKit
 * shapes when it has jawOpen among them, else its presets (vrmExpressions); null without an
 * expression manager.
 */
function vrmDrive(manager) {
  if (!manager) return null;
  const named = Object.keys(manager.customExpressionMap)
    .map((name) => [MORPH_NAMES.indexOf(morphName(name)), name])
    .filter(([k]) => k >= 0);
  if (named.some(([k]) => MORPH_NAMES[k] === 'jawOpen')) {
    return { kind: 'arkit-expressions', set: (weights) => named.forEach(([k, name]) => manager.setValue(name, weights[k])) };
  }
  const sided = manager.getExpression('blinkLeft') && manager.getExpression('blinkRight');
  return {
    kind: 'vrm-presets',
    set(weights) {
      const values = vrmExpressions(weights);
      if (!sided) values.blink = Math.min(values.blinkLeft, values.blinkRight);
      for (const [name, value] of Object.entries(values)) {
        if (manager.getExpression(name)) manager.setValue(name, value);
      }
    },
  };
}

/**
 * The box of a VRM's face (`box`, in world space) and whether it is a skull (`skull`, chin to
 * crown): the vertices skinned mostly to its head, eye and jaw bones (hair and body left out);
 * else the meshes hung from its head bone (not a skull: they may reach down the neck); else a
 * 25 cm box about that bone.
 */
function vrmHeadBox(vrm) {
  const bones = new Set(['head', 'leftEye', 'rightEye', 'jaw'].map((name) => vrm.humanoid.getRawBoneNode(name)));
  const box = new THREE.Box3();
  const vertex = new THREE.Vector3();
  vrm.scene.updateMatrixWorld(true);
  vrm.scene.traverse((obj) => {
    if (!obj.isSkinnedMesh) return;
    const { skinIndex, skinWeight, position } = obj.geometry.attributes;
    const headBones = obj.skeleton.bones.map((bone) => bones.has(bone));
    for (let i = 0; i < position.count; i++) {
      let weight = 0;
      for (let j = 0; j < 4; j++) if (headBones[skinIndex.getComponent(i, j)]) weight += skinWeight.getComponent(i, j);
      if (weight > 0.5) box.expandByPoint(obj.localToWorld(obj.getVertexPosition(i, vertex)));
    }
  });
  const head = vrm.humanoid.getRawBoneNode('head');
  if (!box.isEmpty()) return { box, skull: true };
  box.setFromObject(head); // a head of meshes hung from the bone, not skinned
  if (!box.isEmpty()) return { box, skull: false };
  const centre = head.getWorldPosition(vertex).add(new THREE.Vector3(0, 0.08, 0));
  return { box: box.setFromCenterAndSize(centre, new THREE.Vector3(0.25, 0.25, 0.25)), skull: true };
}

/** A credit line from a VRM's meta: its name, authors and licence. */
function vrmCredit(meta) {
  if (!meta) return null;
  const [name, authors, licence] = meta.metaVersion === '0'
    ? [meta.title, meta.author, meta.otherLicenseUrl || meta.licenseName]
    : [meta.name, (meta.authors || []).join(', '), meta.otherLicenseUrl || meta.licenseUrl];
  return [name, authors && `by ${authors}`, licence && `licence: ${licence}`].filter(Boolean).join(', ') || null;
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

/**
 * Load a GLB or VRM head (meshopt-compressed or not) from `url`; resolves to three.js's glTF
 * result, with a VRM's `userData.vrm`.
 */
export function loadHead(url) {
  const loader = new GLTFLoader();
  loader.setMeshoptDecoder(MeshoptDecoder);
  loader.register((parser) => new VRMLoaderPlugin(parser));
  return loader.loadAsync(url);
}

/** A GLB head on a page: a HeadScene drawn on a canvas that fills `container`. */
export class Avatar3D extends HeadScene {
  /** Load the GLB or VRM at `url` into a canvas appended to `container`. */
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

  expression() {
    return null;
  }

  /** Draw; `idleSeconds` drives the face's own blinks. */
  render(idleSeconds) {
    this.face.setWeights(this.values, idleSeconds);
  }
}

/** A 3D head (GLB or VRM) from `avatarUrl`, or the 2D face (script at `face2dSrc`) when it is null. */
export async function createAvatar(container, avatarUrl, face2dSrc) {
  if (avatarUrl) return Avatar3D.load(container, avatarUrl);
  return Face2DAvatar.load(container, face2dSrc);
}
