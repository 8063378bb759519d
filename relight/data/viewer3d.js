// The results page's 3D view (relight/view/_page3d.py writes window.VIEW3D_DATA before this script): the
// fitted maps on the mesh in WebGL2, shaded like relight.render.Fast without ambient occlusion (SH irradiance,
// split-sum GGX with the DFG table), orbit / zoom with the mouse, an environment-rotation slider, truth | fit |
// error and a map selector. No library, no network. window.VIEW3D.selftest() (the page's #selftest) renders
// offscreen and returns what the test checks (hashes, GL errors, the sphere's pixels).
(function () {
'use strict';
var D = window.VIEW3D_DATA;
if (!D) { return; }
var V = {ready: false, failure: null};
window.VIEW3D = V;
var MODE_NAMES = ['shaded', 'albedo', 'f0', 'roughness', 'normal', 'mfp'];
var SOURCES = {fit: 0, truth: 1, error: 2};
var S = {yaw: D.camera.yaw, pitch: D.camera.pitch, dist: D.camera.distance, rot: 0, source: 0, mode: 0,
         exposure: D.exposure, gain: D.error_gain};
var gl = null, prog = null, U = {}, head = null, sphere = null, T = {}, envPage = null, envConst = null;
var pending = false;

var VS = [
'#version 300 es',
'layout(location=0) in vec3 aPos; layout(location=1) in vec3 aNrm;',
'layout(location=2) in vec2 aUV; layout(location=3) in float aCurv;',
'uniform mat4 uViewProj;',
'out vec3 vPos; out vec3 vNrm; out vec2 vUV; out float vCurv;',
'void main(){vPos=aPos;vNrm=aNrm;vUV=aUV;vCurv=aCurv;gl_Position=uViewProj*vec4(aPos,1.0);}'
].join('\n');

var FS = [
'#version 300 es',
'precision highp float; precision highp int; precision highp sampler2D;',
'in vec3 vPos; in vec3 vNrm; in vec2 vUV; in float vCurv;',
'uniform sampler2D uEnv, uLut, uAlb0, uNrm0, uPar0, uMfp0, uAlb1, uNrm1, uPar1, uMfp1;',
'uniform ivec4 uLevel[8]; uniform int uLevels; uniform float uEnvScale; uniform int uLutN;',
'uniform vec3 uSH[9]; uniform float uRot;',
'uniform vec3 uCam; uniform int uOrtho; uniform vec3 uViewDir; uniform ivec2 uTexSize;',
'uniform int uSource, uMode, uUniform, uMatModel, uRaw;',
'uniform vec3 uMatAlbedo; uniform float uMatF0, uMatAlpha, uMfpMax;',
'uniform float uExposure, uGain, uEta, uTavg, uRawScale;',
'out vec4 outColor;',
'const float PI = 3.14159265358979;',
'struct Mat { vec3 albedo; float f0; float alpha; int model; vec3 n; vec3 mfp; };',
// Light that arrived from d arrives from R d (relight.render.y_rotations): the map is looked up at R^T d.
'vec3 toEnv(vec3 d){float c=cos(uRot), s=sin(uRot); return vec3(c*d.x-s*d.z, d.y, s*d.x+c*d.z);}',
'int imod(int a, int b){return a-b*int(floor(float(a)/float(b)));}',
// relight.envmap.sample_latlong (bilinear between pixel centres, wrap in azimuth, clamp at the poles).
'vec3 latlong(int k, vec3 d){',
' ivec4 r=uLevel[k]; float m=max(max(abs(d.x),abs(d.y)),abs(d.z)); d=d/max(m,1e-30);',
' float v=atan(length(d.xz), d.y)/PI;',
' float u=(abs(d.x)+abs(d.z)>0.0)?(atan(d.x,-d.z)+PI)/(2.0*PI):0.5; if(u>=1.0){u-=1.0;}',
' float y=v*float(r.w)-0.5, x=u*float(r.z)-0.5; float y0=floor(y), x0=floor(x); float fy=y-y0, fx=x-x0;',
' int r0=clamp(int(y0),0,r.w-1), r1=clamp(int(y0)+1,0,r.w-1); int c0=imod(int(x0),r.z), c1=imod(int(x0)+1,r.z);',
' vec3 a=texelFetch(uEnv,ivec2(r.x+c0,r.y+r0),0).rgb, b=texelFetch(uEnv,ivec2(r.x+c1,r.y+r0),0).rgb;',
' vec3 c=texelFetch(uEnv,ivec2(r.x+c0,r.y+r1),0).rgb, e=texelFetch(uEnv,ivec2(r.x+c1,r.y+r1),0).rgb;',
' return ((1.0-fy)*((1.0-fx)*a+fx*b)+fy*((1.0-fx)*c+fx*e))*uEnvScale;}',
// relight.render._fast.lookup_prefiltered: linear in sqrt(alpha) between the two nearest levels.
'vec3 prefiltered(vec3 r, float alpha){',
' int kmax=uLevels-1; float s=clamp(sqrt(max(alpha,0.0))*float(kmax),0.0,float(kmax));',
' int k0=int(floor(s)); int k1=min(k0+1,kmax); float t=s-float(k0);',
' return (1.0-t)*latlong(k0,r)+t*latlong(k1,r);}',
// relight.render._fast.lookup_dfg: bilinear between cell centres, clamped; lut[i (cos_v), j (sqrt alpha)].
'vec2 lut(int i, int j){return texelFetch(uLut,ivec2(j,i),0).rg;}',
'vec2 dfg(float cv, float alpha){',
' float n=float(uLutN); float x=clamp(cv*n-0.5,0.0,n-1.0), y=clamp(sqrt(max(alpha,0.0))*n-0.5,0.0,n-1.0);',
' float x0=floor(x), y0=floor(y); float fx=x-x0, fy=y-y0; int i0=int(x0), j0=int(y0);',
' int i1=min(i0+1,uLutN-1), j1=min(j0+1,uLutN-1);',
' vec2 top=lut(i0,j0)*(1.0-fy)+lut(i0,j1)*fy; vec2 bot=lut(i1,j0)*(1.0-fy)+lut(i1,j1)*fy;',
' return top*(1.0-fx)+bot*fx;}',
// Ramamoorthi & Hanrahan 2001 eq. 7 with relight.envmap's real SH (no Condon-Shortley phase); band l damped by
// exp(-l(l+1) sigma^2 / 2) (the heat kernel on the sphere: the subsurface blur, sigma 0 elsewhere).
'vec3 irradiance(vec3 n, vec3 sig){',
' float x=n.x, y=n.y, z=n.z;',
' vec3 b0=PI*0.28209479177*uSH[0];',
' vec3 b1=(2.0*PI/3.0)*0.48860251190*(uSH[1]*y+uSH[2]*z+uSH[3]*x);',
' vec3 b2=(PI/4.0)*(1.09254843059*(uSH[4]*x*y+uSH[5]*y*z+uSH[7]*x*z)+0.31539156525*uSH[6]*(3.0*z*z-1.0)',
'   +0.54627421529*uSH[8]*(x*x-y*y));',
' vec3 s2=sig*sig; return max(b0+exp(-s2)*b1+exp(-3.0*s2)*b2, 0.0);}',
// brdf.fresnel_dielectric (exact, unpolarised; 1 under total internal reflection).
'float fresnel(float c, float eta){',
' c=clamp(c,0.0,1.0); float s2t=(1.0-c*c)/(eta*eta); if(s2t>=1.0){return 1.0;}',
' float ct=sqrt(1.0-s2t); float a=(eta*c-ct)/(eta*c+ct), b=(c-eta*ct)/(c+eta*ct); return 0.5*(a*a+b*b);}',
'Mat fetchMat(int which){',
' Mat m; vec2 t=vec2(vUV.x,1.0-vUV.y); ivec2 ti=clamp(ivec2(floor(t*vec2(uTexSize))),ivec2(0),uTexSize-1);',
' vec3 nrm; vec4 par;',
' if(which==0){m.albedo=texture(uAlb0,t).rgb; nrm=texture(uNrm0,t).rgb; par=texture(uPar0,t);',
'  m.model=int(texelFetch(uPar0,ti,0).b+0.5); m.mfp=texture(uMfp0,t).rgb;}',
' else{m.albedo=texture(uAlb1,t).rgb; nrm=texture(uNrm1,t).rgb; par=texture(uPar1,t);',
'  m.model=int(texelFetch(uPar1,ti,0).b+0.5); m.mfp=texture(uMfp1,t).rgb;}',
' nrm=2.0*nrm-1.0; float l=length(nrm); m.n=(l>0.5)?nrm/l:normalize(vNrm);',
' m.f0=par.r; m.alpha=par.g; return m;}',
'Mat uniformMat(){Mat m; m.albedo=uMatAlbedo; m.f0=uMatF0; m.alpha=uMatAlpha; m.model=uMatModel;',
' m.n=normalize(vNrm); m.mfp=vec3(0.0); return m;}',
// relight.render.Fast's kernel without ambient occlusion; the subsurface rung as in the module docstring.
'vec3 shade(Mat m, vec3 wo){',
' float cv=dot(wo,m.n); if(cv<=0.0){return vec3(0.0);}',
' vec3 sig=(m.model==4)?min(vCurv*m.mfp,vec3(3.0)):vec3(0.0);',
' vec3 E=irradiance(toEnv(m.n),sig); vec3 col;',
' if(m.model<4){col=m.albedo/PI*E;}else{col=(1.0-fresnel(cv,uEta))/PI*m.albedo*uTavg*E;}',
' if(m.model>=1){vec3 r=2.0*cv*m.n-wo; vec3 pre=prefiltered(toEnv(r),m.alpha);',
'  if(m.model>=2){vec2 ab=dfg(clamp(cv,0.0,1.0),m.alpha); col+=pre*(m.f0*ab.x+ab.y);}else{col+=pre*m.f0;}}',
' return col;}',
'vec3 value(Mat m, vec3 wo){',
' if(uMode==0){return shade(m,wo);} if(uMode==1){return m.albedo;} if(uMode==2){return vec3(m.f0);}',
' if(uMode==3){return vec3(m.alpha);} if(uMode==4){return m.n;} return m.mfp/max(uMfpMax,1e-6);}',
'vec3 srgb(vec3 x){x=clamp(x,0.0,1.0); return mix(12.92*x,1.055*pow(x,vec3(1.0/2.4))-0.055,step(0.0031308,x));}',
'vec3 aces(vec3 x){x=min(x,64.0); return clamp((x*(2.51*x+0.03))/(x*(2.43*x+0.59)+0.14),0.0,1.0);}',
'void main(){',
' vec3 wo=(uOrtho==1)?uViewDir:normalize(uCam-vPos); vec3 v;',
' if(uUniform==1){v=value(uniformMat(),wo);}',
' else if(uSource==2){v=abs(value(fetchMat(0),wo)-value(fetchMat(1),wo))*uGain;}',
' else{v=value(fetchMat(uSource),wo);}',
' v=mix(v,vec3(0.0),vec3(isnan(v))); v=mix(v,vec3(0.0),vec3(isinf(v)));',
' if(uRaw==1){outColor=vec4(v*uRawScale,1.0); return;}',
' if(uMode==0){v=srgb(aces(max(v,0.0)*exp2(uExposure)));}',
' else if(uMode==4&&uSource!=2){v=0.5*v+0.5;}',
' else{v=srgb(v);}',
' outColor=vec4(v,1.0);}'
].join('\n');

function bytes(b64) {
  var s = atob(b64), n = s.length, u = new Uint8Array(n);
  for (var i = 0; i < n; i++) { u[i] = s.charCodeAt(i); }
  return u;
}
function f32(b64) { return new Float32Array(bytes(b64).buffer); }
function u32(b64) { return new Uint32Array(bytes(b64).buffer); }
function u16(b64) { return new Uint16Array(bytes(b64).buffer); }

function shader(type, src) {
  var s = gl.createShader(type);
  gl.shaderSource(s, src);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) { throw new Error('shader: ' + gl.getShaderInfoLog(s)); }
  return s;
}

function geometry(pos, nrm, uv, curv, idx) {
  var vao = gl.createVertexArray();
  gl.bindVertexArray(vao);
  [[pos, 3], [nrm, 3], [uv, 2], [curv, 1]].forEach(function (a, loc) {
    var b = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, b);
    gl.bufferData(gl.ARRAY_BUFFER, a[0], gl.STATIC_DRAW);
    gl.enableVertexAttribArray(loc);
    gl.vertexAttribPointer(loc, a[1], gl.FLOAT, false, 0, 0);
  });
  var e = gl.createBuffer();
  gl.bindBuffer(gl.ELEMENT_ARRAY_BUFFER, e);
  gl.bufferData(gl.ELEMENT_ARRAY_BUFFER, idx, gl.STATIC_DRAW);
  gl.bindVertexArray(null);
  return {vao: vao, count: idx.length};
}

function uvSphere(nLat, nLon) {
  var pos = [], uv = [], idx = [];
  for (var i = 0; i <= nLat; i++) {
    var th = Math.PI * i / nLat;
    for (var j = 0; j <= nLon; j++) {
      var ph = 2 * Math.PI * j / nLon;
      pos.push(Math.sin(th) * Math.sin(ph), Math.cos(th), Math.sin(th) * Math.cos(ph));
      uv.push(j / nLon, 1 - i / nLat);
    }
  }
  for (i = 0; i < nLat; i++) {
    for (j = 0; j < nLon; j++) {
      var a = i * (nLon + 1) + j, b = a + nLon + 1;
      idx.push(a, b, a + 1, a + 1, b, b + 1);
    }
  }
  var p = new Float32Array(pos), c = new Float32Array(p.length / 3).fill(1);
  return geometry(p, p, new Float32Array(uv), c, new Uint32Array(idx));
}

function texture(internal, format, type, w, h, data, filter) {
  var t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
  gl.pixelStorei(gl.UNPACK_FLIP_Y_WEBGL, false);
  gl.pixelStorei(gl.UNPACK_PREMULTIPLY_ALPHA_WEBGL, false);
  gl.pixelStorei(gl.UNPACK_COLORSPACE_CONVERSION_WEBGL, gl.NONE);
  if (w === null) { gl.texImage2D(gl.TEXTURE_2D, 0, internal, format, type, data); }
  else { gl.texImage2D(gl.TEXTURE_2D, 0, internal, w, h, 0, format, type, data); }
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, filter);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, filter);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, gl.CLAMP_TO_EDGE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, gl.CLAMP_TO_EDGE);
  return t;
}

function image(id, srgb) {
  var img = document.getElementById(id);
  if (!img || !img.complete || !img.naturalWidth) { throw new Error('texture image ' + id + ' did not load'); }
  return texture(srgb ? gl.SRGB8 : gl.RGB8, gl.RGB, gl.UNSIGNED_BYTE, null, null, img, gl.LINEAR);
}

function half(b64, w, h) { return texture(gl.RGBA16F, gl.RGBA, gl.HALF_FLOAT, w, h, u16(b64), gl.LINEAR); }

function environment(atlas, w, h, sh, scale) {
  return {tex: texture(gl.RGBA16F, gl.RGBA, gl.HALF_FLOAT, w, h, atlas, gl.NEAREST), sh: new Float32Array(sh),
          scale: scale};
}

function init() {
  if (V.ready || V.failure) { return; }
  try {
    var canvas = document.getElementById('v3d-canvas');
    gl = canvas.getContext('webgl2', {alpha: false, antialias: true, preserveDrawingBuffer: true});
    if (!gl) { throw new Error('this browser has no WebGL2'); }
    V.floatTarget = !!gl.getExtension('EXT_color_buffer_float');
    prog = gl.createProgram();
    gl.attachShader(prog, shader(gl.VERTEX_SHADER, VS));
    gl.attachShader(prog, shader(gl.FRAGMENT_SHADER, FS));
    gl.linkProgram(prog);
    if (!gl.getProgramParameter(prog, gl.LINK_STATUS)) { throw new Error('link: ' + gl.getProgramInfoLog(prog)); }
    var n = gl.getProgramParameter(prog, gl.ACTIVE_UNIFORMS);
    for (var i = 0; i < n; i++) {
      var name = gl.getActiveUniform(prog, i).name.replace(/\[0\]$/, '');
      U[name] = gl.getUniformLocation(prog, name);
    }
    var M = D.mesh;
    head = geometry(f32(M.positions), f32(M.normals), f32(M.uv), f32(M.curvature), u32(M.indices));
    sphere = uvSphere(48, 96);
    var tw = D.texture_size[0], th = D.texture_size[1];
    var zero = texture(gl.RGBA16F, gl.RGBA, gl.HALF_FLOAT, 1, 1, new Uint16Array(4), gl.NEAREST);
    ['fit', 'truth'].forEach(function (k) {
      var s = D.sets[k];
      if (!s) { return; }
      T[k] = {albedo: image(s.albedo, true), normal: image(s.normal, false), params: half(s.params, tw, th),
              mfp: s.mfp ? half(s.mfp, tw, th) : zero};
    });
    if (!T.truth) { T.truth = T.fit; }
    var E = D.environment;
    envPage = environment(u16(E.atlas), E.atlas_size[0], E.atlas_size[1], E.sh, E.scale);
    // The self-test's constant environment: the same atlas layout, every texel the sphere's radiance.
    envConst = environment(new Uint16Array(E.atlas_size[0] * E.atlas_size[1] * 4).fill(D.sphere.half),
                           E.atlas_size[0], E.atlas_size[1], D.sphere.sh, 1.0);
    T.lut = texture(gl.RG32F, gl.RG, gl.FLOAT, E.lut_size, E.lut_size, f32(E.lut), gl.NEAREST);
    V.mfpMax = D.mfp_max || 1;
    controls(canvas);
    fromHash(canvas);
    V.ready = true;
    schedule();
  } catch (err) {
    V.failure = String(err && err.message || err);
    var st = document.getElementById('v3d-status');
    if (st) { st.textContent = '3D view unavailable: ' + V.failure; }
  }
}

// ---------------------------------------------------------------- matrices (column-major)

function mul(a, b) {
  var o = new Float32Array(16);
  for (var c = 0; c < 4; c++) {
    for (var r = 0; r < 4; r++) {
      var s = 0;
      for (var k = 0; k < 4; k++) { s += a[k * 4 + r] * b[c * 4 + k]; }
      o[c * 4 + r] = s;
    }
  }
  return o;
}
function perspective(fovy, aspect, near, far) {
  var f = 1 / Math.tan(fovy / 2), nf = 1 / (near - far);
  return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
}
function sub(a, b) { return [a[0] - b[0], a[1] - b[1], a[2] - b[2]]; }
function cross(a, b) { return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]; }
function unit(a) { var l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; }
function dot(a, b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }
function lookAt(eye, at) {
  var z = unit(sub(eye, at)), x = unit(cross([0, 1, 0], z)), y = cross(z, x);
  return new Float32Array([x[0], y[0], z[0], 0, x[1], y[1], z[1], 0, x[2], y[2], z[2], 0,
                           -dot(x, eye), -dot(y, eye), -dot(z, eye), 1]);
}
function eyeOf(st) {
  var t = D.camera.target, cp = Math.cos(st.pitch);
  return [t[0] + st.dist * cp * Math.sin(st.yaw), t[1] + st.dist * Math.sin(st.pitch),
          t[2] + st.dist * cp * Math.cos(st.yaw)];
}

// ---------------------------------------------------------------- drawing

function bindTex(unit, tex, name) {
  gl.activeTexture(gl.TEXTURE0 + unit);
  gl.bindTexture(gl.TEXTURE_2D, tex);
  if (U[name]) { gl.uniform1i(U[name], unit); }
}

// Draw into the bound framebuffer (w x h). opt: {st, sphere: material or null, env, raw, rawScale}.
function render(w, h, opt) {
  var st = opt.st, env = opt.env || envPage, levels = D.environment.levels, lv = new Int32Array(32);
  gl.viewport(0, 0, w, h);
  gl.clearColor(0.12, 0.12, 0.12, 0);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  gl.enable(gl.DEPTH_TEST);
  gl.disable(gl.CULL_FACE);
  gl.useProgram(prog);
  var vp, eye;
  if (opt.sphere) {
    var s = 1 / 1.05;
    vp = new Float32Array([s, 0, 0, 0, 0, s, 0, 0, 0, 0, -0.5, 0, 0, 0, 0, 1]);
    eye = [0, 0, 10];
  } else {
    eye = eyeOf(st);
    var r = D.camera.radius, near = Math.max(st.dist - 2 * r, st.dist * 0.01), far = st.dist + 2 * r;
    vp = mul(perspective(D.camera.fov_deg * Math.PI / 180, w / h, near, far), lookAt(eye, D.camera.target));
  }
  gl.uniformMatrix4fv(U.uViewProj, false, vp);
  gl.uniform3fv(U.uCam, eye);
  gl.uniform1i(U.uOrtho, opt.sphere ? 1 : 0);
  gl.uniform3fv(U.uViewDir, [0, 0, 1]);
  for (var k = 0; k < levels.length; k++) { lv.set(levels[k], 4 * k); }
  gl.uniform4iv(U.uLevel, lv);
  gl.uniform1i(U.uLevels, levels.length);
  gl.uniform1f(U.uEnvScale, env.scale);
  gl.uniform1i(U.uLutN, D.environment.lut_size);
  gl.uniform3fv(U.uSH, env.sh);
  gl.uniform1f(U.uRot, st.rot * Math.PI / 180);
  gl.uniform2i(U.uTexSize, D.texture_size[0], D.texture_size[1]);
  gl.uniform1i(U.uSource, st.source);
  gl.uniform1i(U.uMode, st.mode);
  gl.uniform1i(U.uUniform, opt.sphere ? 1 : 0);
  var m = opt.sphere || {albedo: [0, 0, 0], f0: 0, alpha: 0, model: 0};
  gl.uniform3fv(U.uMatAlbedo, m.albedo);
  gl.uniform1f(U.uMatF0, m.f0);
  gl.uniform1f(U.uMatAlpha, m.alpha);
  gl.uniform1i(U.uMatModel, m.model);
  gl.uniform1f(U.uMfpMax, V.mfpMax);
  gl.uniform1i(U.uRaw, opt.raw ? 1 : 0);
  gl.uniform1f(U.uRawScale, opt.rawScale || 1);
  gl.uniform1f(U.uExposure, st.exposure);
  gl.uniform1f(U.uGain, st.gain || D.error_gain);
  gl.uniform1f(U.uEta, D.eta);
  gl.uniform1f(U.uTavg, D.t_avg);
  bindTex(0, env.tex, 'uEnv');
  bindTex(1, T.lut, 'uLut');
  ['fit', 'truth'].forEach(function (key, i) {
    var t = T[key];
    bindTex(2 + 4 * i, t.albedo, 'uAlb' + i);
    bindTex(3 + 4 * i, t.normal, 'uNrm' + i);
    bindTex(4 + 4 * i, t.params, 'uPar' + i);
    bindTex(5 + 4 * i, t.mfp, 'uMfp' + i);
  });
  var g = opt.sphere ? sphere : head;
  gl.bindVertexArray(g.vao);
  gl.drawElements(gl.TRIANGLES, g.count, gl.UNSIGNED_INT, 0);
  gl.bindVertexArray(null);
}

function draw() {
  pending = false;
  if (!V.ready) { return; }
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  render(gl.canvas.width, gl.canvas.height, {st: S});
}
function schedule() {
  if (!pending) { pending = true; requestAnimationFrame(draw); }
}

// ---------------------------------------------------------------- controls

function controls(canvas) {
  var home = {yaw: S.yaw, pitch: S.pitch, dist: S.dist}, drag = null;
  canvas.addEventListener('pointerdown', function (e) {
    drag = {x: e.clientX, y: e.clientY};
    try { canvas.setPointerCapture(e.pointerId); } catch (err) { /* a synthetic pointer (the self-test) */ }
  });
  canvas.addEventListener('pointermove', function (e) {
    if (!drag) { return; }
    S.yaw -= (e.clientX - drag.x) * 0.01;
    S.pitch = Math.max(-1.5, Math.min(1.5, S.pitch + (e.clientY - drag.y) * 0.01));
    drag = {x: e.clientX, y: e.clientY};
    schedule();
  });
  canvas.addEventListener('pointerup', function () { drag = null; });
  canvas.addEventListener('pointercancel', function () { drag = null; });
  canvas.addEventListener('wheel', function (e) {
    e.preventDefault();
    var r = D.camera.radius;
    S.dist = Math.max(1.05 * r, Math.min(20 * r, S.dist * Math.exp(e.deltaY * 0.001)));
    schedule();
  }, {passive: false});
  canvas.addEventListener('dblclick', function () {
    S.yaw = home.yaw; S.pitch = home.pitch; S.dist = home.dist; schedule();
  });
  var rot = document.getElementById('v3d-rot'), label = document.getElementById('v3d-rot-label');
  rot.addEventListener('input', function () {
    S.rot = parseFloat(rot.value); label.textContent = rot.value + '\u00b0'; schedule();
  });
  Array.prototype.forEach.call(document.querySelectorAll('input[name="v3d-source"]'), function (el) {
    el.addEventListener('change', function () { if (el.checked) { S.source = SOURCES[el.value]; schedule(); } });
  });
  var sel = document.getElementById('v3d-map');
  sel.addEventListener('change', function () { S.mode = parseInt(sel.value, 10); schedule(); });
  var gain = document.getElementById('v3d-gain');
  gain.addEventListener('change', function () { S.gain = parseFloat(gain.value); schedule(); });
  var exp = document.getElementById('v3d-exp');
  exp.addEventListener('input', function () {
    var x = parseFloat(exp.value);
    if (isFinite(x)) { S.exposure = x; schedule(); }
  });
}

// A first state from the address: index.html#view3d=source:error,map:0,rot:90,yaw:30,pitch:10,zoom:1.5,gain:4 (angles
// in degrees, zoom divides the distance); shot:1 pins the canvas to the window's top left corner, over the page
// (what scripts/screenshot_view3d.py photographs).
function fromHash(canvas) {
  var h = location.hash;
  if (h.indexOf('#view3d=') !== 0) { return; }
  decodeURIComponent(h.slice(8)).split(',').forEach(function (kv) {
    var p = kv.split(':'), k = p[0], v = p[1], x = parseFloat(v);
    if (k === 'source' && SOURCES.hasOwnProperty(v) && (v === 'fit' || D.sets.truth)) {
      S.source = SOURCES[v];
      Array.prototype.forEach.call(document.querySelectorAll('input[name="v3d-source"]'),
                                   function (el) { el.checked = el.value === v; });
    } else if (k === 'map' && x >= 0 && x < MODE_NAMES.length) {
      S.mode = Math.floor(x); document.getElementById('v3d-map').value = String(S.mode);
    } else if (k === 'rot' && isFinite(x)) {
      S.rot = ((Math.round(x) % 360) + 360) % 360;
      document.getElementById('v3d-rot').value = String(S.rot);
      document.getElementById('v3d-rot-label').textContent = S.rot + '\u00b0';
    } else if (k === 'yaw' && isFinite(x)) { S.yaw += x * Math.PI / 180; }
    else if (k === 'pitch' && isFinite(x)) { S.pitch = Math.max(-1.5, Math.min(1.5, S.pitch + x * Math.PI / 180)); }
    else if (k === 'zoom' && x > 0) { S.dist = Math.max(1.05 * D.camera.radius, S.dist / x); }
    else if (k === 'gain' && x > 0) { S.gain = x; }
    else if (k === 'shot' && x === 1) {
      canvas.style.position = 'fixed'; canvas.style.left = '0'; canvas.style.top = '0'; canvas.style.zIndex = '10';
    }
  });
}

// ---------------------------------------------------------------- self-test

function target(w, h, float) {
  var fb = gl.createFramebuffer(), color = gl.createRenderbuffer(), depth = gl.createRenderbuffer();
  gl.bindRenderbuffer(gl.RENDERBUFFER, color);
  gl.renderbufferStorage(gl.RENDERBUFFER, float ? gl.RGBA32F : gl.RGBA8, w, h);
  gl.bindRenderbuffer(gl.RENDERBUFFER, depth);
  gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT24, w, h);
  gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
  gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.RENDERBUFFER, color);
  gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth);
  if (gl.checkFramebufferStatus(gl.FRAMEBUFFER) !== gl.FRAMEBUFFER_COMPLETE) {
    throw new Error('framebuffer incomplete');
  }
  return {fb: fb, w: w, h: h, float: float};
}

function frame(tg, opt) {
  gl.bindFramebuffer(gl.FRAMEBUFFER, tg.fb);
  render(tg.w, tg.h, opt);
  var px = tg.float ? new Float32Array(tg.w * tg.h * 4) : new Uint8Array(tg.w * tg.h * 4);
  gl.readPixels(0, 0, tg.w, tg.h, gl.RGBA, tg.float ? gl.FLOAT : gl.UNSIGNED_BYTE, px);
  return px;
}

function hash(px) {
  var h = 2166136261;
  for (var i = 0; i < px.length; i++) { h ^= px[i]; h = Math.imul(h, 16777619) >>> 0; }
  return h.toString(16);
}

function changed(a, b) {
  var n = 0;
  for (var i = 0; i < a.length; i += 4) {
    if (a[i] !== b[i] || a[i + 1] !== b[i + 1] || a[i + 2] !== b[i + 2]) { n++; }
  }
  return n / (a.length / 4);
}

function covered(px) {
  var n = 0;
  for (var i = 3; i < px.length; i += 4) { if (px[i] > 0) { n++; } }
  return n / (px.length / 4);
}

function round(x) { return Number(x.toPrecision(6)); }

// The analytic sphere (uniform material) seen orthographically along -z: [nx, ny, nz, r, g, b] per covered pixel.
function spherePixels(tg, mat, env, rot) {
  var st = {yaw: 0, pitch: 0, dist: 1, rot: rot, source: 0, mode: 0, exposure: 0};
  var scale = tg.float ? 1 : 0.5;  // 8-bit fallback: radiance x 0.5 (known), read back x 2
  var rad = frame(tg, {st: st, sphere: mat, env: env, raw: true, rawScale: scale});
  st.mode = 4;  // the normal: raw on a float target, else as displayed (0.5 n + 0.5, no transfer curve)
  var nrm = frame(tg, {st: st, sphere: mat, env: env, raw: tg.float});
  var out = [], k = tg.float ? 1 : 255;
  for (var i = 0; i < rad.length; i += 4) {
    if (rad[i + 3] <= 0) { continue; }
    var n = [nrm[i] / k, nrm[i + 1] / k, nrm[i + 2] / k];
    if (!tg.float) { n = [2 * n[0] - 1, 2 * n[1] - 1, 2 * n[2] - 1]; }
    out.push(n.concat([rad[i] / k / scale, rad[i + 1] / k / scale, rad[i + 2] / k / scale]).map(round));
  }
  return out;
}

// The controls driven as a user would (events on the canvas and the inputs): the state they set and whether
// the picture changed; the state is put back after.
function interact(tg) {
  var c = gl.canvas, saved = Object.assign({}, S), out = {};
  var first = frame(tg, {st: S});
  var ev = function (type, x, y) {
    c.dispatchEvent(new PointerEvent(type, {clientX: x, clientY: y, pointerId: 7, bubbles: true}));
  };
  ev('pointerdown', 100, 100); ev('pointermove', 150, 120); ev('pointerup', 150, 120);
  c.dispatchEvent(new WheelEvent('wheel', {deltaY: 200, bubbles: true, cancelable: true}));
  out.yaw = S.yaw - saved.yaw; out.pitch = S.pitch - saved.pitch; out.zoom = S.dist / saved.dist;
  out.dragged = hash(frame(tg, {st: S})) !== hash(first);
  var rot = document.getElementById('v3d-rot');
  rot.value = '45'; rot.dispatchEvent(new Event('input'));
  var sel = document.getElementById('v3d-map');
  sel.value = '1'; sel.dispatchEvent(new Event('change'));
  var err = document.querySelector('input[name="v3d-source"][value="error"]');
  if (!err.disabled) { err.checked = true; err.dispatchEvent(new Event('change')); }
  out.rot = S.rot; out.mode = S.mode; out.source = S.source;
  c.dispatchEvent(new MouseEvent('dblclick', {bubbles: true}));
  out.home = S.yaw === saved.yaw && S.pitch === saved.pitch && S.dist === saved.dist;
  Object.assign(S, saved);
  rot.value = String(S.rot); sel.value = String(S.mode);
  document.querySelector('input[name="v3d-source"][value="fit"]').checked = true;
  return out;
}

V.selftest = function () {
  var out = {webgl2: false};
  try {
    init();
    out.webgl2 = !!gl;
    out.failure = V.failure;
    if (!V.ready) { return out; }
    var errors = [];
    var check = function (what) {
      for (var e = gl.getError(); e !== gl.NO_ERROR; e = gl.getError()) { errors.push(what + ': ' + e); }
    };
    check('init');
    var w = 160, h = 120, tg = target(w, h, false);
    var base = {yaw: S.yaw, pitch: S.pitch, dist: S.dist, rot: 0, source: 0, mode: 0, exposure: S.exposure,
                gain: D.error_gain};
    var with_ = function (k, v) { var s = Object.assign({}, base); s[k] = v; return s; };
    var f0 = frame(tg, {st: base}), fr = frame(tg, {st: with_('rot', 90)});
    var fo = frame(tg, {st: with_('yaw', base.yaw + 40 * Math.PI / 180)});
    var fp = frame(tg, {st: with_('pitch', base.pitch + 20 * Math.PI / 180)});
    check('frames');
    out.size = [w, h];
    out.hashes = {base: hash(f0), rotated: hash(fr), orbited: hash(fo), pitched: hash(fp)};
    out.changed = {rotation: changed(f0, fr), orbit: changed(f0, fo), pitch: changed(f0, fp)};
    out.covered = covered(f0);
    out.modes = {};
    var sources = D.sets.truth ? ['fit', 'truth', 'error'] : ['fit'];
    sources.forEach(function (src) {
      MODE_NAMES.forEach(function (name, m) {
        var s = Object.assign({}, base, {source: SOURCES[src], mode: m});
        out.modes[src + '/' + name] = hash(frame(tg, {st: s}));
      });
    });
    check('modes');
    out.interaction = interact(tg);
    check('interaction');
    out.float_target = V.floatTarget;
    var sz = 40, sp = target(sz, sz, V.floatTarget);
    var skin = {albedo: [0.5, 0.4, 0.3], f0: 0.04, alpha: 0.3, model: 2};
    var metal = {albedo: [0, 0, 0], f0: 0.9, alpha: 0.5, model: 2};
    var cases = [['skin, constant', skin, envConst, 0], ['specular, constant', metal, envConst, 0],
                 ['skin, page environment', skin, envPage, 0], ['skin, page environment turned', skin, envPage, 90]];
    out.sphere = {size: sz, radiance: D.sphere.radiance, cases: cases.map(function (c) {
      return {name: c[0], albedo: c[1].albedo, f0: c[1].f0, alpha: c[1].alpha, model: c[1].model,
              environment: c[2] === envConst ? 'constant' : 'page', rotation_deg: c[3],
              pixels: spherePixels(sp, c[1], c[2], c[3])};
    })};
    check('sphere');
    out.gl_errors = errors;
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    draw();
  } catch (err) {
    out.failure = String(err && err.message || err);
  }
  return out;
};

if (document.readyState === 'complete') { init(); } else { window.addEventListener('load', init); }
})();
