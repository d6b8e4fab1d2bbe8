// Build the web app into src/vispeech/serve/static/: bundle the three page scripts and the
// stimuli renderer's (three.js included, shared code split into chunks/), copy the pages, the
// style sheet and the 2D face.
// The folder is generated: it is emptied first and ignores itself in git.
import { build } from 'esbuild';
import { copyFileSync, mkdirSync, rmSync, writeFileSync } from 'node:fs';
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';

const here = dirname(fileURLToPath(import.meta.url));
const src = join(here, 'src');
const out = join(here, '..', 'src', 'vispeech', 'serve', 'static');
const face2d = join(here, '..', 'src', 'vispeech', 'preview', 'face2d.js');

rmSync(out, { recursive: true, force: true });
mkdirSync(out, { recursive: true });
writeFileSync(join(out, '.gitignore'), '# Built by web/build.mjs (npm run build); not kept in git.\n*\n');

await build({
  entryPoints: ['chat.js', 'player.js', 'viewer.js', 'stimuli.js'].map((name) => join(src, name)),
  outdir: out,
  bundle: true,
  splitting: true,
  format: 'esm',
  chunkNames: 'chunks/shared-[hash]',
  minify: true,
  target: ['es2022'],
  legalComments: 'eof',
  logLevel: 'warning',
});

for (const name of ['index.html', 'player.html', 'viewer.html', 'style.css']) {
  copyFileSync(join(src, name), join(out, name));
}
copyFileSync(face2d, join(out, 'face2d.js'));
console.log(`built ${out}`);
