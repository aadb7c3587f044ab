// dnr-three: EXT_deferred_neural_rendering for three.js.
export { DNRGLTFPlugin, EXTENSION } from './plugin.js';
export { DNRNeuralLayer, probeGPU, pinholeOf } from './layer.js';
export { getDecoder, Decoder } from './decoder.js';
