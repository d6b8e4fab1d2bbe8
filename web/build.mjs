// Build the web app into src/vispeech/serve/static/: bundle the three page scripts and the
// stimuli renderer's (three.js included, shared code split into chunks/), copy the pages, the
// style sheet and the 2D face, and Swagger UI's script and style for the API docs at /docs
// (served from here, so that the docs work offline).
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
const swagger = join(here, 'node_modules', 'swagger-ui-dist');
mkdirSync(join(out, 'swagger-ui'));
for (const name of ['swagger-ui-bundle.js', 'swagger-ui-bundle.js.LICENSE.txt', 'swagger-ui.css', 'LICENSE']) {
  copyFileSync(join(swagger, name), join(out, 'swagger-ui', name));
}
console.log(`built ${out}`);
