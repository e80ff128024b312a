// The glossary: every name the dashboard's plots show, with the name engineers use, its unit and
// what it means. Plots name their traces with ``label(code)``; the glossary page lists them all.
// One entry per code as the API sends it (health parameters, tuners, sensors, auxiliary outputs,
// engineering-unit performance, fault hypotheses, operating condition).

const HEALTH = [
  ["fan_eff", "Fan efficiency", "Fan isentropic efficiency scalar: change from the nominal engine; negative is deterioration. A fuel-metering offset reads as fan efficiency (about 60 % of what is left of its level's error on the built-in engine, with a design that has no bias tuners)."],
  ["fan_flow", "Fan flow capacity", "Fan corrected-flow scalar: negative is deterioration (fouling, erosion)."],
  ["lpc_eff", "LPC efficiency", "Low-pressure compressor (booster) efficiency scalar."],
  ["lpc_flow", "LPC flow capacity", "Low-pressure compressor corrected-flow scalar."],
  ["hpc_eff", "HPC efficiency", "High-pressure compressor efficiency scalar; a water wash recovers part of its loss."],
  ["hpc_flow", "HPC flow capacity", "High-pressure compressor corrected-flow scalar. The gas-path sensors cannot tell it from the engine's VSV rigging: on the built-in engine, with a design that has no bias tuners, rigging offsets are about 70 % of what is left of its level's error, so read its change since the baseline rather than its level, and expect a step where VSVs were re-rigged."],
  ["hpt_eff", "HPT efficiency", "High-pressure turbine efficiency scalar."],
  ["hpt_flow", "HPT flow capacity", "High-pressure turbine flow scalar: erosion raises it (positive is deterioration)."],
  ["lpt_eff", "LPT efficiency", "Low-pressure turbine efficiency scalar."],
  ["lpt_flow", "LPT flow capacity", "Low-pressure turbine flow scalar: positive is deterioration."],
  ["wf_bias", "Fuel-flow bias", "Fuel-flow actuator bias, in percent of the commanded flow."],
  ["vsv_bias", "VSV bias", "Variable stator vane actuator bias, in percent of the command."],
  ["vbv_bias", "VBV bias", "Variable bleed valve actuator bias, in percent of the command."],
].map(([code, name, meaning]) => ({ code, name, unit: "%", group: "Health parameters", meaning }));

const TUNERS = Array.from({ length: 13 }, (_, i) => ({
  code: `q${i + 1}`, name: `Tuner ${i + 1}`, unit: "%", group: "Tuners",
  meaning: `Tuning parameter ${i + 1} of the design: a combination of health parameters that the sensors can estimate (a design has fewer tuners than health parameters).`,
}));

const SENSORS = [
  ["Nf", "Fan speed (N1)", "rpm", "Physical fan (low-pressure spool) speed."],
  ["Nc", "Core speed (N2)", "rpm", "Physical core (high-pressure spool) speed."],
  ["T24", "LPC outlet temperature (T24)", "degR", "LPC outlet total temperature."],
  ["P24", "LPC outlet pressure (P24)", "psia", "LPC outlet total pressure."],
  ["T30", "HPC outlet temperature (T30)", "degR", "HPC outlet total temperature."],
  ["Ps30", "HPC outlet static pressure (Ps30)", "psia", "HPC outlet static pressure."],
  ["P30", "HPC outlet pressure (P30)", "psia", "HPC outlet total pressure."],
  ["T48", "EGT (T48)", "degR", "HPT outlet total temperature: the exhaust gas temperature of the cockpit."],
  ["P50", "LPT outlet pressure (P50)", "psia", "LPT outlet total pressure."],
  ["T50", "LPT outlet temperature (T50)", "degR", "LPT outlet total temperature."],
  ["P15", "Bypass pressure (P15)", "psia", "Bypass-duct total pressure."],
  ["Wf", "Fuel flow (Wf)", "pps", "Fuel flow command; as a fault hypothesis, a fuel-flow actuator bias."],
  ["VSV", "VSV position", "%", "Variable stator vane position; as a fault hypothesis, a VSV actuator bias."],
  ["VBV", "VBV position", "%", "Variable bleed valve position; as a fault hypothesis, a VBV actuator bias."],
].map(([code, name, unit, meaning]) => ({ code, name, unit, group: "Sensors and actuators", meaning }));

const AUX = [
  ["Fn", "Net thrust", "lbf", "Net thrust estimated from the health parameters at the record's flight condition; in lbf per flight phase on the performance panels."],
  ["T40", "Turbine inlet temperature (T40)", "degR", "Burner outlet, HPT inlet total temperature (not measured: estimated)."],
  ["SM_fan", "Fan stall margin", "margin points", "Distance of the fan operating point from its stall line, in margin points on the performance panels."],
  ["SM_LPC", "LPC stall margin", "margin points", "Distance of the low-pressure compressor operating point from its stall line, in margin points on the performance panels."],
  ["SM_HPC", "HPC stall margin", "margin points", "Distance of the high-pressure compressor operating point from its stall line, in margin points on the performance panels."],
  ["BPR", "Bypass ratio", "1", "Bypass flow over core flow."],
].map(([code, name, unit, meaning]) => ({ code, name, unit, group: "Thrust, temperatures and stall margins",
  meaning: `${meaning} For the built-in engine the engine page shows it in its unit on the performance panels; for another engine type its "Estimated auxiliary outputs" plot gives its change from the type's nominal engine in percent (the API's aux group, and the CSV, keep that percent for every type).` }));

const PERFORMANCE = [
  ["egt_margin", "EGT margin", "degC", "Red-line EGT minus the take-off EGT corrected to ISA+15 K: what is left before the limit."],
  ["dEGT", "ΔEGT", "degC", "EGT minus the baseline engine's EGT at the same condition (corrected, smoothed): the deviation trend."],
  ["dWf", "ΔWf (fuel flow)", "%", "Fuel flow against the baseline at the same condition, smoothed."],
  ["dN2", "ΔN2 (core speed)", "%", "Core speed against the baseline at the same condition, smoothed."],
  ["dN1", "ΔN1 (fan speed)", "%", "Fan speed against the baseline at the same condition, smoothed."],
  ["Fn_rated", "Thrust in % of rated", "% of rated", "Net thrust in percent of the rated take-off thrust (sea level, ISA)."],
  ["thrust_deficit", "Thrust deficit", "%", "Thrust short of the nominal engine at the same condition."],
  ["SM_fan_change", "Fan stall-margin change", "margin points", "Fan stall margin against the engine's baseline."],
  ["SM_LPC_change", "LPC stall-margin change", "margin points", "LPC stall margin against the engine's baseline."],
  ["SM_HPC_change", "HPC stall-margin change", "margin points", "HPC stall margin against the engine's baseline."],
  ["T40_change", "ΔT40 (turbine inlet temperature)", "degC", "Estimated turbine inlet temperature minus the nominal engine's at the same condition (not measured: from the health estimates)."],
].map(([code, name, unit, meaning]) => ({ code, name, unit, group: "Performance in engineering units", meaning }));

const FAULTS = [
  ["Fan", "Fan fault", "An abrupt fan damage: fan efficiency and flow capacity drop together."],
  ["LPC", "LPC fault", "An abrupt low-pressure compressor damage."],
  ["HPC", "HPC fault", "An abrupt high-pressure compressor damage."],
  ["HPT", "HPT fault", "An abrupt high-pressure turbine damage: efficiency down, flow capacity up."],
  ["LPT", "LPT fault", "An abrupt low-pressure turbine damage: efficiency down, flow capacity up."],
  ["Wf bias", "Fuel-flow bias fault", "A fuel-flow actuator bias."],
  ["VSV bias", "VSV bias fault", "A variable stator vane actuator bias."],
  ["VBV bias", "VBV bias fault", "A variable bleed valve actuator bias."],
].map(([code, name, meaning]) => ({ code, name, unit: "", group: "Fault hypotheses", meaning }));

const CONDITION = [
  ["alt_ft", "Altitude", "ft", "Pressure altitude of the record."],
  ["mach", "Mach number", "1", "Flight Mach number."],
  ["dtamb_k", "ISA deviation", "K", "Ambient temperature minus the standard atmosphere's."],
  ["power_pct", "Power setting", "%", "Throttle (power lever) setting in percent of take-off."],
].map(([code, name, unit, meaning]) => ({ code, name, unit, group: "Flight condition", meaning }));

const TERMS = [
  ["σ", "1-sigma (σ)", "", "One standard deviation of an estimate: bands and hovers show the value ± 1σ."],
  ["WSSR", "WSSR", "1", "Weighted sum of squared residuals of a fault hypothesis: how badly the hypothesis explains the shift; a hypothesis is accepted below the threshold."],
  ["SSEE", "SSEE", "%²", "Sum of squared estimation errors over the health parameters (squared bias plus variance)."],
  ["baseline", "Baseline", "", "The engine's first settled records after installation or a shop visit: health changes are measured from it."],
  ["design", "Estimator design", "", "The choice of sensors, tuners and Kalman gain that turns the records into health estimates; the active design is the one in service."],
  ["events", "Events", "", "Detected shifts and wear alerts, marked ▼ on the trends."],
].map(([code, name, unit, meaning]) => ({ code, name, unit, group: "Terms", meaning }));

export const GLOSSARY = [...HEALTH, ...AUX, ...PERFORMANCE, ...TUNERS, ...SENSORS, ...FAULTS, ...CONDITION, ...TERMS];
const BY_CODE = new Map(GLOSSARY.map((e) => [e.code, e]));

// The entry of a code as the API sends it, or null. A phase suffix (``Fn (cruise)``) keeps its
// phase: ``Net thrust (cruise)``.
export function entry(code) {
  return BY_CODE.get(String(code)) || null;
}

// The engineers' name of a code (the code itself when the glossary does not know it).
export function label(code) {
  const text = String(code);
  const phase = text.match(/^(.*) \(([a-z]+)\)$/);
  if (phase && BY_CODE.has(phase[1])) return `${BY_CODE.get(phase[1]).name} (${phase[2]})`;
  return BY_CODE.has(text) ? BY_CODE.get(text).name : text;
}

// The engineers' name of a fault hypothesis (the WSSR group names the actuator-bias hypotheses
// by their actuator: ``Wf`` is the fuel-flow bias fault).
export function faultLabel(code) {
  const e = BY_CODE.get(`${code} bias`) || BY_CODE.get(String(code));
  return e && e.group === "Fault hypotheses" ? e.name : label(code);
}
