// Charts (uPlot): the clearance over time and the drive curves against their limits, all sharing one time
// cursor (a vertical line drawn at the current time). Clicking a chart moves the time there.
import uPlot from 'uplot';

function cursorPlugin(owner) {
  return {
    hooks: {
      draw: [(u) => {
        if (owner.cursorT === null || owner.cursorT === undefined) return;
        const x = u.valToPos(owner.cursorT, 'x', true);
        const ctx = u.ctx;
        ctx.save();
        ctx.strokeStyle = '#ef4444';
        ctx.lineWidth = 2 * (window.devicePixelRatio || 1);
        ctx.beginPath();
        ctx.moveTo(x, u.bbox.top);
        ctx.lineTo(x, u.bbox.top + u.bbox.height);
        ctx.stroke();
        ctx.restore();
      }],
    },
  };
}

function clickToTime(u, onTime) {
  u.over.addEventListener('click', () => {
    if (u.cursor.left === null || u.cursor.left < 0) return;
    onTime(u.posToVal(u.cursor.left, 'x'));
  });
}

function width(el) { return Math.max(320, (el.clientWidth || 800) - 10); }

export class ClearanceChart {
  constructor(el, clearance, requested, onTime) {
    this.cursorT = 0;
    el.innerHTML = '';
    const t = clearance.t_s;
    const d = clearance.distance_m.map((v) => (v === null ? null : 1000 * v));
    const req = t.map(() => 1000 * requested);
    this.plot = new uPlot({
      width: width(el), height: 180,
      scales: { x: { time: false } },
      axes: [{ label: 't [s]' }, { label: 'distance [mm]' }],
      series: [{}, { label: 'closest pair distance', stroke: '#2563eb', width: 2 },
        { label: 'requested clearance', stroke: '#b42318', dash: [6, 4], width: 1 }],
      plugins: [cursorPlugin(this)],
      legend: { live: false },
    }, [t, d, req], el);
    clickToTime(this.plot, onTime);
  }

  cursor(t) { this.cursorT = t; this.plot.redraw(false, false); }
  destroy() { this.plot.destroy(); }
}

const QUANTITIES = [
  { key: 'position', label: 'position', unit: (u) => u, lower: 'lower', upper: 'upper' },
  { key: 'velocity', label: 'velocity', unit: (u) => `${u}/s`, sym: 'v_max' },
  { key: 'acceleration', label: 'acceleration', unit: (u) => `${u}/s²`, sym: 'a_max' },
  { key: 'jerk', label: 'jerk', unit: (u) => `${u}/s³`, sym: 'j_max' },
  { key: 'effort', label: 'force', unit: (u) => (u === 'm' ? 'N' : 'N m'), sym: 'effort_max' },
];

// Drive curves of one drive at a time (a selector picks it): every quantity the profile has, against its
// limits (from the scene document for cabin8, from the profile's own "limits" for pprs6).
export class DriveCharts {
  constructor(el, select, profile, scene, onTime) {
    this.el = el;
    this.select = select;
    this.profile = profile;
    this.scene = scene;
    this.onTime = onTime;
    this.plots = [];
    this.cursorT = 0;
    select.innerHTML = profile.drives.map((d, i) => `<option value="${i}">${d}</option>`).join('');
    this.onChange = () => this.draw(Number(select.value));
    select.addEventListener('change', this.onChange);
    this.draw(0);
  }

  limitsOf(q, k) {
    if (this.scene && this.scene.limits) {
      const L = this.scene.limits;
      if (q.lower) return [L.lower[k], L.upper[k]];
      if (L[q.sym]) return [-L[q.sym][k], L[q.sym][k]];
      return null;
    }
    const L = this.profile.limits || {};
    const name = this.profile.drives[k];
    if (q.sym && L[q.sym] && L[q.sym][name] !== undefined) return [-L[q.sym][name], L[q.sym][name]];
    return null;
  }

  draw(k) {
    for (const p of this.plots) p.destroy();
    this.plots = [];
    this.el.innerHTML = '';
    const t = this.profile.t;
    const units = this.scene ? this.scene.drive_units : this.profile.drives.map((n) => this.profile.units.position[n]);
    for (const q of QUANTITIES) {
      const rows = this.profile[q.key];
      if (!rows) continue; // e.g. no jerk in this profile
      const box = document.createElement('div');
      box.className = 'drive-chart';
      box.dataset.quantity = q.key;
      this.el.appendChild(box);
      const y = rows.map((r) => r[k]);
      const lim = this.limitsOf(q, k);
      const data = [t, y];
      const series = [{}, { label: `${this.profile.drives[k]} ${q.label}`, stroke: '#1d4ed8', width: 1.5 }];
      if (lim) {
        data.push(t.map(() => lim[0]), t.map(() => lim[1]));
        series.push({ label: q.lower ? 'lower limit' : '-limit', stroke: '#b42318', dash: [6, 4] },
          { label: q.lower ? 'upper limit' : '+limit', stroke: '#b42318', dash: [6, 4] });
      }
      const plot = new uPlot({
        width: Math.max(300, Math.floor(((this.el.clientWidth || 900) - 20) / 2)), height: 150,
        scales: { x: { time: false } },
        axes: [{ label: 't [s]' }, { label: `${q.label} [${q.unit(units[k])}]`, size: 60 }],
        series,
        plugins: [cursorPlugin(this)],
        legend: { live: false },
      }, data, box);
      clickToTime(plot, this.onTime);
      this.plots.push(plot);
    }
  }

  cursor(t) { this.cursorT = t; for (const p of this.plots) p.redraw(false, false); }
  destroy() { this.select.removeEventListener('change', this.onChange); for (const p of this.plots) p.destroy(); this.el.innerHTML = ''; }
}
