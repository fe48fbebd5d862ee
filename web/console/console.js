// polmap console (GET / of `polmap serve`): the map (landmarks, gridmap, coverage, version
// diffs, the HD-map overlay of a stored comparison), landmark details with their version
// history, map versions and the fleet, from the server's own API. No inline script, no CDN:
// everything comes from this server (CSP in mapping_service/server/src/server_console.cpp).
// The operator key lives in this script's memory only: it is sent as an Authorization
// header, never put into a URL, the page's address or storage.
'use strict';

(function () {
  const COLORS = {
    odd: '#22c55e', even: '#d946ef', mixed: '#f59e0b', unknown: '#9ca3af', line: '#38bdf8',
    added: '#f8fafc', moved: '#2563eb', retired: '#dc2626', coverage: '#facc15',
    err0: '#22d3ee', err1: '#a3e635', err2: '#facc15', err3: '#ef4444', noerr: '#737373',
    tracking: '#60a5fa', degraded: '#f97316', lost: '#b91c1c', initializing: '#a3a3a3',
    weak: '#ef4444', fine: '#22c55e',
    hdMatched: '#84cc16', hdUnmatched: '#f97316', mapMatched: '#e0f2fe', mapUnmatched: '#e11d48',
    outside: '#6b7280',
  };
  // Run colouring by |lateral error| (m): the legend's classes.
  const ERROR_COLOUR = ['case', ['==', ['get', 'abs_err_lat_m'], null], COLORS.noerr,
    ['step', ['get', 'abs_err_lat_m'], COLORS.err0, 0.05, COLORS.err1, 0.15, COLORS.err2, 0.3, COLORS.err3]];
  const STATUS_COLOUR = ['match', ['get', 'status'], 'tracking', COLORS.tracking, 'degraded', COLORS.degraded,
    'lost', COLORS.lost, COLORS.initializing];
  // HD-map overlay: matched / unmatched / outside the compared area, per role.
  const hdColor = (matched, unmatched) => ['case',
    ['!', ['all', ['get', 'in_area'], ['coalesce', ['get', 'judged'], true]]], COLORS.outside,
    ['get', 'matched'], matched, unmatched];
  const HDMAP_LAYERS = ['hdmap-hd-lines', 'hdmap-map-lines', 'hdmap-hd-points', 'hdmap-map-points'];
  const state = { key: null, tilejson: null, map: null, versions: [], current: null };
  const $ = (id) => document.getElementById(id);

  function headers() {
    return state.key ? { Authorization: 'Bearer ' + state.key } : {};
  }

  async function sendJson(method, path, body) {
    const h = headers();
    if (body !== undefined) h['Content-Type'] = 'application/json';
    const res = await fetch(path, { method, headers: h, body: body === undefined ? undefined : JSON.stringify(body) });
    let j = null;
    try { j = await res.json(); } catch (e) { /* 204: no body */ }
    if (!res.ok) throw new Error(method + ' ' + path + ': ' + ((j && j.error) || res.status));
    return j;
  }

  async function getJson(path, withKey) {
    const res = await fetch(path, { headers: withKey ? headers() : {}, cache: 'no-cache' });
    if (!res.ok) {
      let msg = res.status + ' ' + res.statusText;
      try { msg = (await res.json()).error || msg; } catch (e) { /* not JSON */ }
      throw new Error(path.split('?')[0] + ': ' + msg);
    }
    return res.json();
  }

  function text(el, s) { el.textContent = s; return el; }

  function cell(tr, s) { tr.appendChild(text(document.createElement('td'), String(s))); }

  // ------------------------------------------------------------------ the map
  function style(tj, gridmapMaxZoom) {
    const p = tj.polmap || {};
    const sources = {
      landmarks: {
        type: 'vector', tiles: tj.tiles, minzoom: tj.minzoom, maxzoom: tj.maxzoom,
        bounds: tj.bounds,
      },
      diff: { type: 'geojson', data: { type: 'FeatureCollection', features: [] } },
      run: { type: 'geojson', data: { type: 'FeatureCollection', features: [] } },
      quality: { type: 'geojson', data: { type: 'FeatureCollection', features: [] } },
      hdmap: { type: 'geojson', data: { type: 'FeatureCollection', features: [] } },
    };
    const layers = [{ id: 'background', type: 'background', paint: { 'background-color': '#0c0c10' } }];
    if (p.gridmap_tiles) {
      sources.gridmap = { type: 'raster', tiles: [p.gridmap_tiles], tileSize: 256, minzoom: 14, maxzoom: gridmapMaxZoom, bounds: tj.bounds };
      sources.mechanism = { type: 'raster', tiles: [p.gridmap_mechanism_tiles], tileSize: 256, minzoom: 14, maxzoom: gridmapMaxZoom, bounds: tj.bounds };
      layers.push({ id: 'gridmap', type: 'raster', source: 'gridmap', paint: { 'raster-opacity': 0.85 } });
      layers.push({ id: 'gridmap-mechanism', type: 'raster', source: 'mechanism', layout: { visibility: 'none' }, paint: { 'raster-opacity': 0.85 } });
    }
    layers.push(
      { id: 'quality', type: 'fill', source: 'quality', layout: { visibility: 'none' },
        paint: { 'fill-color': ['case', ['get', 'weak'], COLORS.weak, COLORS.fine],
          'fill-opacity': ['case', ['get', 'weak'], 0.45, 0.15], 'fill-outline-color': '#0c0c10' } },
      { id: 'coverage', type: 'line', source: 'landmarks', 'source-layer': 'trajectories', layout: { visibility: 'none' },
        paint: { 'line-color': COLORS.coverage, 'line-width': 2, 'line-opacity': 0.6 } },
      { id: 'lines', type: 'line', source: 'landmarks', 'source-layer': 'lines',
        paint: { 'line-color': COLORS.line, 'line-width': ['interpolate', ['linear'], ['zoom'], 14, 1, 20, 3] } },
      { id: 'points', type: 'circle', source: 'landmarks', 'source-layer': 'points',
        paint: {
          'circle-radius': ['interpolate', ['linear'], ['zoom'], 14, 1.5, 20, 6],
          'circle-color': ['match', ['get', 'class'], 'odd', COLORS.odd, 'even', COLORS.even, 'mixed', COLORS.mixed, COLORS.unknown],
        } },
      { id: 'run', type: 'line', source: 'run', layout: { visibility: 'none', 'line-cap': 'round' },
        paint: { 'line-width': ['interpolate', ['linear'], ['zoom'], 14, 3, 20, 7], 'line-color': ERROR_COLOUR } },
      { id: 'diff-lines', type: 'line', source: 'diff', filter: ['==', ['geometry-type'], 'LineString'], layout: { visibility: 'none' },
        paint: { 'line-width': 4, 'line-color': ['match', ['get', 'change'], 'added', COLORS.added, 'moved', COLORS.moved, COLORS.retired] } },
      { id: 'diff-points', type: 'circle', source: 'diff', filter: ['==', ['geometry-type'], 'Point'], layout: { visibility: 'none' },
        paint: { 'circle-radius': 6, 'circle-stroke-width': 1, 'circle-stroke-color': '#fff',
          'circle-color': ['match', ['get', 'change'], 'added', COLORS.added, 'moved', COLORS.moved, COLORS.retired] } },
      // HD features wide and under the landmarks; HD points as rings around them.
      { id: 'hdmap-hd-lines', type: 'line', source: 'hdmap', layout: { visibility: 'none' },
        filter: ['all', ['==', ['get', 'role'], 'hd'], ['==', ['geometry-type'], 'LineString']],
        paint: { 'line-width': 6, 'line-opacity': 0.55, 'line-color': hdColor(COLORS.hdMatched, COLORS.hdUnmatched) } },
      { id: 'hdmap-map-lines', type: 'line', source: 'hdmap', layout: { visibility: 'none' },
        filter: ['all', ['==', ['get', 'role'], 'map'], ['==', ['geometry-type'], 'LineString']],
        paint: { 'line-width': 2, 'line-color': hdColor(COLORS.mapMatched, COLORS.mapUnmatched) } },
      { id: 'hdmap-hd-points', type: 'circle', source: 'hdmap', layout: { visibility: 'none' },
        filter: ['all', ['==', ['get', 'role'], 'hd'], ['==', ['geometry-type'], 'Point']],
        paint: { 'circle-radius': 7, 'circle-opacity': 0, 'circle-stroke-width': 2.5,
          'circle-stroke-color': hdColor(COLORS.hdMatched, COLORS.hdUnmatched) } },
      { id: 'hdmap-map-points', type: 'circle', source: 'hdmap', layout: { visibility: 'none' },
        filter: ['all', ['==', ['get', 'role'], 'map'], ['==', ['geometry-type'], 'Point']],
        paint: { 'circle-radius': 3.5, 'circle-color': hdColor(COLORS.mapMatched, COLORS.mapUnmatched) } },
    );
    return { version: 8, sources, layers };
  }

  function setVisible(ids, on) {
    for (const id of ids) {
      if (state.map.getLayer(id)) state.map.setLayoutProperty(id, 'visibility', on ? 'visible' : 'none');
    }
  }

  function gridmapLayers() {
    const on = $('layer-gridmap').checked;
    const mech = document.querySelector('input[name="gridmap-style"]:checked').value === 'mechanism';
    setVisible(['gridmap'], on && !mech);
    setVisible(['gridmap-mechanism'], on && mech);
  }

  function fixed(v, digits, unit) {
    return v === undefined || v === null ? undefined : Number(v).toFixed(digits) + (unit || '');
  }

  function addRows(dl, rows) {
    for (const [k, v] of rows) {
      if (v === undefined || v === null) continue;
      dl.appendChild(text(document.createElement('dt'), k));
      dl.appendChild(text(document.createElement('dd'), String(v)));
    }
  }

  function hdmapPopup(f) {
    const dl = document.createElement('dl');
    dl.className = 'popup';
    const p = f.properties;
    const status = !p.in_area ? 'outside the compared area'
      : p.judged === false ? 'not judged (the other map has nothing of this kind here)'
        : p.matched ? 'matched' : 'unmatched';
    addRows(dl, [[p.role === 'hd' ? 'HD-map feature' : 'map landmark (HD comparison)', p.type],
      ['subtype', p.subtype || undefined], ['status', status], ['HD id', p.hd_id], ['landmark', p.key],
      ['matched landmark', p.landmark_key], ['matched HD type', p.hd_type],
      ['offset', fixed(p.distance_m, 3, ' m')], ['median offset', fixed(p.median_offset_m, 3, ' m')],
      ['length', fixed(p.length_m, 1, ' m')],
      ['HD line covered', p.line_coverage === undefined || p.line_coverage === null ? undefined : Math.round(100 * p.line_coverage) + ' %']]);
    return dl;
  }

  function when(iso) { return iso ? iso.replace('T', ' ').replace('Z', ' UTC') : undefined; }

  // first/last seen: drive times when the drives' clock is UTC (the server says so with an
  // ISO time), otherwise when the drives were uploaded.
  function seen(d, which) {
    if (d[which + '_seen']) return when(d[which + '_seen']);
    const up = d[which + '_ingested_at'];
    return up ? when(up) + ' (upload)' : '—';
  }

  async function landmarkDetails(p, dl) {
    if (!p.key || !p.map_version) return;
    try {
      const d = await getJson('/v1/maps/' + encodeURIComponent(p.map_version) + '/landmarks/' + encodeURIComponent(p.key), true);
      addRows(dl, [['supporting drives (stored)', d.supporting_drives], ['first seen', seen(d, 'first')], ['last seen', seen(d, 'last')]]);
      dl.appendChild(text(document.createElement('dt'), 'history'));
      const dd = document.createElement('dd');
      const ol = document.createElement('ol');
      ol.className = 'history';
      for (const h of d.history) {
        const r = h.reason && h.reason.rule ? ' · ' + h.reason.rule : '';
        const moved = h.change === 'moved' ? ' ' + Number(h.distance_m).toFixed(2) + ' m' : '';
        const note = h.inferred ? ' (first version)' : '';
        text(ol.appendChild(document.createElement('li')),
          'v' + h.version + ' ' + h.change + moved + r + note + (h.published_at ? ' · ' + h.published_at.slice(0, 10) : ''));
      }
      if (!d.history.length) text(ol.appendChild(document.createElement('li')), 'no recorded changes');
      dd.appendChild(ol);
      dl.appendChild(dd);
      if (d.drives) {
        addRows(dl, [['drives', d.drives.map((x) => x.drive_id).join(', ')]]);
      }
      window.polmapConsole.landmark = d;
      // Several popups may load at once (a point on a line): each by its key too.
      (window.polmapConsole.landmarks = window.polmapConsole.landmarks || {})[String(p.key)] = d;
    } catch (e) {
      addRows(dl, [['details', String(e.message || e)]]);
    }
  }

  function popupFor(f) {
    if (f.layer.id.startsWith('hdmap-')) return hdmapPopup(f);
    const dl = document.createElement('dl');
    dl.className = 'popup';
    const p = f.properties;
    const rows = [['kind', f.layer.id === 'points' ? 'point' : f.layer.id === 'lines' ? 'line' : f.layer.id],
      // The key as a string: a 63-bit id read as a JavaScript number is rounded.
      ['id', p.key !== undefined ? p.key : p.id], ['class', p['class']], ['support (drives)', p.support_drives],
      ['spread', p.spread_m !== undefined ? Number(p.spread_m).toFixed(3) + ' m' : undefined],
      ['map version', p.map_version], ['change', p.change], ['moved by', p.distance_m !== undefined ? Number(p.distance_m).toFixed(3) + ' m' : undefined],
      ['drive', p.drive_id], ['vehicle', p.vehicle_id]];
    if (f.layer.id === 'run') {
      rows.splice(0, rows.length, ['kind', 'run sample'], ['status', p.status],
        ['lateral error', p.err_lat_m !== undefined && p.err_lat_m !== null ? Number(p.err_lat_m).toFixed(3) + ' m' : 'not evaluated'],
        ['lateral σ', Number(p.sigma_lat_m).toFixed(3) + ' m'], ['distance', Number(p.distance_m).toFixed(1) + ' m'],
        ['time', Number(p.t_s).toFixed(2) + ' s']);
    } else if (f.layer.id === 'quality') {
      rows.splice(0, rows.length, ['kind', 'fleet localization quality'], ['cell', p.tile], ['runs', p.runs + ' against map v' + p.map_version],
        ['samples', p.samples], ['degraded or lost', (100 * Number(p.degraded_share)).toFixed(1) + ' %'],
        ['mean lateral σ', Number(p.mean_sigma_lat_m).toFixed(3) + ' m'],
        ['lateral RMSE', p.lat_rmse_m !== undefined && p.lat_rmse_m !== null ? Number(p.lat_rmse_m).toFixed(3) + ' m' : 'no reference'],
        ['weak', p.weak ? 'yes' : 'no']);
    }
    addRows(dl, rows);
    // Landmarks: support times and version history from the server.
    if (f.layer.id === 'points' || f.layer.id === 'lines') {
      if (p.key !== undefined) dl.dataset.key = String(p.key);
      landmarkDetails(p, dl);
    }
    return dl;
  }

  function initMap(tj, gridmapMaxZoom) {
    const map = new maplibregl.Map({
      container: 'map',
      style: style(tj, gridmapMaxZoom),
      center: [tj.center[0], tj.center[1]],
      zoom: tj.center[2],
      hash: true,  // #zoom/lat/lon keeps the view
      attributionControl: { compact: true, customAttribution: 'polmap' },
      // The key goes into a header of our own requests only (coverage needs it).
      transformRequest: (url) => {
        if (state.key && url.startsWith(window.location.origin + '/v1/mvt/')) return { url, headers: headers() };
        return { url };
      },
    });
    map.addControl(new maplibregl.NavigationControl(), 'top-left');
    map.addControl(new maplibregl.ScaleControl({ unit: 'metric', maxWidth: 120 }), 'bottom-left');
    map.on('error', (e) => { $('version-label').textContent = 'map error: ' + ((e.error && e.error.message) || e); });
    const clickable = ['points', 'lines', 'diff-points', 'diff-lines', 'run', 'hdmap-hd-points', 'hdmap-map-points',
      'hdmap-map-lines', 'hdmap-hd-lines', 'coverage', 'quality'];
    map.on('click', (e) => {
      // A few pixels of slack: point landmarks are small circles.
      const b = [[e.point.x - 4, e.point.y - 4], [e.point.x + 4, e.point.y + 4]];
      const fs = map.queryRenderedFeatures(b, { layers: clickable.filter((id) => map.getLayer(id)) })
        .sort((x, y) => clickable.indexOf(x.layer.id) - clickable.indexOf(y.layer.id));
      if (!fs.length) return;
      // A landmark and its change in the diff may lie on top of each other: show each once.
      const box = document.createElement('div');
      box.className = 'popup-box';
      const seen = new Set();
      for (const f of fs) {
        if (seen.has(f.layer.id) || seen.size >= 3) continue;
        seen.add(f.layer.id);
        box.appendChild(popupFor(f));
      }
      new maplibregl.Popup({ maxWidth: '20em' }).setLngLat(e.lngLat).setDOMContent(box).addTo(map);
    });
    for (const id of clickable) {
      map.on('mouseenter', id, () => { map.getCanvas().style.cursor = 'pointer'; });
      map.on('mouseleave', id, () => { map.getCanvas().style.cursor = ''; });
    }
    map.once('load', () => { state.loaded = true; });
    state.map = map;
    window.polmapConsole.map = map;
    return map;
  }

  // ------------------------------------------------------------------ versions and diffs
  function fillVersions() {
    const body = $('versions').querySelector('tbody');
    body.replaceChildren();
    const from = $('diff-from'), to = $('diff-to');
    from.replaceChildren();
    to.replaceChildren();
    const published = state.versions.filter((v) => v.status === 'published');
    for (const v of state.versions.slice().reverse()) {
      const tr = document.createElement('tr');
      const s = v.statistics || {};
      cell(tr, v.version + (v.current ? ' (current)' : ''));
      cell(tr, v.status);
      cell(tr, s.point_landmarks ?? '');
      cell(tr, s.line_landmarks ?? '');
      cell(tr, (v.published_at || '').replace('T', ' ').replace('Z', ''));
      body.appendChild(tr);
    }
    for (const v of published) {
      from.appendChild(text(document.createElement('option'), String(v.version))).value = String(v.version);
      to.appendChild(text(document.createElement('option'), String(v.version))).value = String(v.version);
    }
    if (published.length >= 2) {
      from.value = String(published[published.length - 2].version);
      to.value = String(published[published.length - 1].version);
    }
  }

  async function showDiff() {
    const from = $('diff-from').value, to = $('diff-to').value;
    if (!from || !to || from === to) { $('diff-summary').textContent = 'choose two different versions'; return; }
    const d = await getJson('/v1/maps/' + encodeURIComponent(to) + '/diff?from=' + encodeURIComponent(from) + '&format=geojson');
    state.map.getSource('diff').setData(d);
    const s = (d.properties && d.properties.counts) || {};
    $('diff-summary').textContent = 'v' + from + ' → v' + to + ': ' + (s.added || 0) + ' added, ' + (s.moved || 0) + ' moved, ' + (s.retired || 0) + ' retired';
    $('layer-diff').disabled = false;
    $('layer-diff').checked = true;
    setVisible(['diff-points', 'diff-lines'], true);
    window.polmapConsole.diff = d;
  }

  // ------------------------------------------------------------------ HD-map overlay
  function pct(v) { return v === null || v === undefined ? 'n/a' : (100 * v).toFixed(1) + ' %'; }
  function metres(v) { return v === null || v === undefined ? 'n/a' : Number(v).toFixed(3) + ' m'; }

  async function showHdmap(name) {
    const summary = $('hdmap-summary');
    const g = await getJson('/v1/maps/' + state.current + '/hdmap-comparison/' + encodeURIComponent(name) + '?format=geojson');
    state.map.getSource('hdmap').setData(g);
    const s = (g.properties && g.properties.summary) || {};
    const dl = document.createElement('dl');
    dl.className = 'summary';
    addRows(dl, [['HD map', g.properties.hdmap_file || name],
      ['point precision', pct(s.point_precision)], ['point recall', pct(s.point_recall)],
      ['matched points', (s.matched_points ?? 0) + ' of ' + (s.map_points ?? 0) + ' map / ' + (s.hd_points ?? 0) + ' HD'],
      ['median point offset', metres(s.point_median_offset_m)],
      ['line coverage', pct(s.line_coverage) + ' of ' + Number(s.line_total_length_m || 0).toFixed(0) + ' m'],
      ['median lateral line offset', metres(s.line_median_lateral_offset_m)]]);
    summary.replaceChildren(dl);
    window.polmapConsole.hdmap = g;
  }

  // The comparisons stored with the current version (polmap compare-hdmap --store).
  async function loadHdmap() {
    const box = $('layer-hdmap'), select = $('hdmap-name'), summary = $('hdmap-summary');
    select.replaceChildren();
    let list = [];
    try {
      list = (await getJson('/v1/maps/' + state.current + '/hdmap-comparison')).comparisons;
    } catch (e) {
      summary.textContent = String(e.message || e);
    }
    for (const c of list) select.appendChild(text(document.createElement('option'), c.name)).value = c.name;
    select.disabled = list.length < 2;
    box.disabled = list.length === 0;
    if (!list.length) {
      box.checked = false;
      setVisible(HDMAP_LAYERS, false);
      state.map.getSource('hdmap').setData({ type: 'FeatureCollection', features: [] });
      summary.textContent = 'no HD-map comparison stored for version ' + state.current + ' (polmap compare-hdmap --store)';
      window.polmapConsole.hdmap = null;
      return;
    }
    await showHdmap(list[0].name);
  }

  // ------------------------------------------------------------------ fleet
  // A drive's place in the current map: ingested after that version was started → not in a
  // map yet; named in its excluded drives → excluded; otherwise used by it.
  function driveStatus(r, cur) {
    if (!cur) return 'new';
    const excluded = ((cur.parameters || {}).excluded_drive_ids || []).includes(r.drive_id);
    if (excluded) return 'excluded from v' + cur.version;
    if (r.ingested_at && cur.created_at && r.ingested_at > cur.created_at) return 'new (next build)';
    return 'in v' + cur.version;
  }

  // Survey-grade (RTK, < 0.1 m) or consumer-grade positioning, from the drive's manifest.
  function positioningLabel(p) {
    const m = Number(p.median_std_m);
    if (!Number.isFinite(m)) return '';
    return (m <= 0.1 ? 'survey ' : 'consumer ') + (m < 1 ? (100 * m).toFixed(0) + ' cm' : m.toFixed(1) + ' m');
  }

  // The drive's day when its clock is UTC (after 2000), else the day it was uploaded.
  function driveDate(r) {
    if (r.start_time_s > 946684800) return new Date(r.start_time_s * 1000).toISOString().slice(0, 10);
    return r.ingested_at ? r.ingested_at.slice(0, 10) + ' (upload)' : '';
  }

  async function loadFleet() {
    const status = $('fleet-status');
    const body = $('drives').querySelector('tbody');
    body.replaceChildren();
    if (!state.key) { status.textContent = 'enter an operator key to see the drives'; return; }
    try {
      const d = await getJson('/v1/drives', true);
      const cur = (state.versions || []).find((v) => v.version === state.current);
      for (const r of d.drives) {
        const tr = document.createElement('tr');
        cell(tr, r.drive_id);
        cell(tr, driveStatus(r, cur));
        cell(tr, r.vehicle_id);
        cell(tr, r.distance_m !== undefined ? (r.distance_m / 1000).toFixed(2) : '');
        cell(tr, r.positioning ? positioningLabel(r.positioning) : '');
        cell(tr, driveDate(r));
        const td = document.createElement('td');
        const del = text(document.createElement('button'), 'delete');
        del.type = 'button';
        del.setAttribute('aria-label', 'delete drive ' + r.drive_id);
        del.addEventListener('click', () => deleteDrive(r.drive_id));
        td.appendChild(del);
        tr.appendChild(td);
        body.appendChild(tr);
      }
      status.textContent = d.count + ' drives';
      $('layer-coverage').disabled = false;
      $('build-start').disabled = false;
      // The coverage layer's tiles depend on the key: fetch them again with it.
      const src = state.map.getSource('landmarks');
      if (src && src.setTiles) src.setTiles(state.tilejson.tiles.slice());
    } catch (e) {
      status.textContent = String(e.message || e);
    }
  }

  // ------------------------------------------------------------------ localization runs
  const SVG = 'http://www.w3.org/2000/svg';

  function svg(tag, attrs, parent) {
    const e = document.createElementNS(SVG, tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, String(v));
    if (parent) parent.appendChild(e);
    return e;
  }

  // |lateral error| and the localizer's lateral σ against distance: the paper's spatially
  // resolved error, as a plot. Gaps where samples were not evaluated.
  function plotRun(g) {
    const plot = $('run-plot');
    for (const c of Array.from(plot.childNodes)) if (c.nodeName !== 'title') plot.removeChild(c);
    const fs = g.features.map((f) => f.properties);
    const W = 320, H = 150, L = 38, R = 8, T = 8, B = 24;
    const dmax = Math.max(1, ...fs.map((p) => p.distance_m));
    const errs = fs.filter((p) => p.abs_err_lat_m !== null).map((p) => p.abs_err_lat_m);
    const ymax = Math.max(0.1, ...errs.map((e) => e * 1.1), ...fs.map((p) => Math.min(p.sigma_lat_m, 1)));
    const x = (d) => L + (W - L - R) * d / dmax;
    const y = (e) => H - B - (H - T - B) * Math.min(e, ymax) / ymax;
    for (let k = 0; k <= 4; ++k) {
      const v = ymax * k / 4;
      svg('line', { class: 'grid', x1: L, x2: W - R, y1: y(v), y2: y(v) }, plot);
      svg('text', { x: L - 4, y: y(v) + 3, 'text-anchor': 'end' }, plot).textContent = v.toFixed(2);
    }
    for (let k = 0; k <= 4; ++k) {
      const d = dmax * k / 4;
      svg('text', { x: x(d), y: H - B + 12, 'text-anchor': 'middle' }, plot).textContent = d.toFixed(0);
    }
    svg('path', { class: 'axis', d: `M${L} ${T}V${H - B}H${W - R}` }, plot);
    const path = (key) => {
      let d = '', pen = false;
      for (const p of fs) {
        const v = p[key];
        if (v === null || v === undefined) { pen = false; continue; }
        d += (pen ? 'L' : 'M') + x(p.distance_m).toFixed(1) + ' ' + y(v).toFixed(1);
        pen = true;
      }
      return d;
    };
    svg('path', { class: 'sigma', d: path('sigma_lat_m') || 'M0 0' }, plot);
    svg('path', { class: 'curve', d: path('abs_err_lat_m') || 'M0 0' }, plot);
    $('run-figure').hidden = false;
  }

  function runColouring() {
    if (!state.map.getLayer('run')) return;
    const by = document.querySelector('input[name="run-colour"]:checked').value;
    state.map.setPaintProperty('run', 'line-color', by === 'status' ? STATUS_COLOUR : ERROR_COLOUR);
  }

  // Sources exist once the style is loaded (asynchronously, even from an object).
  function styleReady() {
    return state.loaded ? Promise.resolve() : new Promise((res) => state.map.once('load', res));
  }

  async function showRun(id, fit) {
    const g = await getJson('/v1/runs/' + encodeURIComponent(id) + '?format=geojson', true);
    await styleReady();
    state.map.getSource('run').setData(g);
    const r = g.properties || {};
    const s = r.summary || {};
    const pct = (v) => (100 * (v || 0)).toFixed(0) + ' %';
    const m = (v) => (v === null || v === undefined ? 'n/a' : Number(v).toFixed(3) + ' m');
    $('run-summary').textContent = 'run ' + r.id + ' (' + (r.label || 'no label') + ', vehicle ' + (r.vehicle_id || 'unnamed') +
      ', map v' + r.map_version + ', ' + (r.received_at || '').replace('T', ' ').replace('Z', ' UTC') + '): ' +
      (s.length_m / 1000).toFixed(2) + ' km, tracking ' + pct(s.status_share && s.status_share.tracking) +
      ', degraded ' + pct(s.status_share && s.status_share.degraded) + ', lateral RMSE ' + m(s.lat_rmse_m) +
      ', longitudinal ' + m(s.long_rmse_m) + ', reference: ' + s.reference;
    for (const tr of $('runs').querySelectorAll('tbody tr')) tr.classList.toggle('selected', tr.dataset.run === String(id));
    // Colour by error when the run has errors, else by status.
    const byError = (s.evaluated || 0) > 0;
    document.querySelector('input[name="run-colour"][value="' + (byError ? 'error' : 'status') + '"]').checked = true;
    runColouring();
    $('layer-run').disabled = false;
    $('layer-run').checked = true;
    setVisible(['run'], true);
    plotRun(g);
    if (fit && r.bounds) {
      state.map.fitBounds([[r.bounds.min_lon_deg, r.bounds.min_lat_deg], [r.bounds.max_lon_deg, r.bounds.max_lat_deg]], { padding: 40 });
    }
    window.polmapConsole.run = g;
  }

  async function loadQuality() {
    // By default each cell shows the runs against the newest map version that has runs there.
    const all = $('quality-all-runs').checked;
    const g = await getJson('/v1/runs/quality' + (all ? '?runs=all' : ''), true);
    await styleReady();
    state.map.getSource('quality').setData(g);
    $('layer-quality').disabled = false;
    $('quality-all-runs').disabled = false;
    window.polmapConsole.quality = g;
  }

  async function loadRuns() {
    const status = $('runs-status');
    const body = $('runs').querySelector('tbody');
    body.replaceChildren();
    if (!state.key) { status.textContent = 'enter an operator key to see the runs'; return; }
    try {
      const d = await getJson('/v1/runs?limit=50', true);
      for (const r of d.runs) {
        const s = r.summary || {};
        const tr = document.createElement('tr');
        tr.dataset.run = String(r.id);
        cell(tr, r.id);
        cell(tr, r.label);
        cell(tr, ((s.length_m || 0) / 1000).toFixed(2));
        cell(tr, s.lat_rmse_m === null || s.lat_rmse_m === undefined ? 'n/a' : Number(s.lat_rmse_m).toFixed(3));
        cell(tr, (100 * ((s.status_share && s.status_share.tracking) || 0)).toFixed(0) + ' %');
        const td = document.createElement('td');
        const show = text(document.createElement('button'), 'show');
        show.type = 'button';
        show.setAttribute('aria-label', 'show run ' + r.id + ' on the map');
        show.addEventListener('click', () => showRun(r.id, true).catch((e) => { status.textContent = String(e.message || e); }));
        td.appendChild(show);
        tr.appendChild(td);
        body.appendChild(tr);
      }
      status.textContent = d.count + ' runs' + (d.count ? '' : ' (polmap localize --report URL sends one)');
      await loadQuality();
      if (d.runs.length) await showRun(d.runs[0].id, false);  // the newest, where the view is
    } catch (e) {
      status.textContent = String(e.message || e);
    }
  }

  // ------------------------------------------------------------------ operator actions
  async function deleteDrive(id) {
    if (!window.confirm('Delete drive ' + id + ' and its package? The next build leaves it out.')) return;
    try {
      await sendJson('DELETE', '/v1/drives/' + encodeURIComponent(id));
      $('fleet-status').textContent = 'drive ' + id + ' deleted';
    } catch (e) {
      $('fleet-status').textContent = String(e.message || e);
    }
    await loadFleet();
  }

  async function refreshVersions() {
    const list = await getJson('/v1/maps');
    state.versions = list.versions;
    state.current = list.current;
    fillVersions();
    $('version-label').textContent = 'map version ' + list.current;
    loadHdmap();
    // Tiles of "current" changed: fetch them again.
    const p = state.tilejson.polmap || {};
    const urls = { landmarks: state.tilejson.tiles, gridmap: [p.gridmap_tiles], mechanism: [p.gridmap_mechanism_tiles] };
    for (const [id, tiles] of Object.entries(urls)) {
      const src = state.map.getSource(id);
      if (src && src.setTiles && tiles[0]) src.setTiles(tiles.slice());
    }
  }

  async function startBuild() {
    const status = $('build-status'), bar = $('build-progress');
    $('build-start').disabled = true;
    try {
      const r = await sendJson('POST', '/v1/maps', { notes: 'started from the console' });
      bar.hidden = false;
      for (;;) {
        const v = await getJson('/v1/maps/' + r.version, false);
        const p = v.progress || {};
        bar.value = p.fraction || 0;
        const text = 'version ' + r.version + ': ' + v.status + (p.stage ? ' (' + p.stage + ', ' + Math.round(100 * (p.fraction || 0)) + ' %)' : '');
        if (v.status !== 'building') {
          // "published" only once the map shows the new version (label, versions, tiles).
          if (v.status === 'published') await refreshVersions();
          status.textContent = text + (v.error ? ': ' + v.error : '');
          break;
        }
        status.textContent = text;
        await new Promise((res) => setTimeout(res, 300));
      }
    } catch (e) {
      status.textContent = String(e.message || e);
    } finally {
      bar.hidden = true;
      $('build-start').disabled = !state.key;
    }
  }

  // ------------------------------------------------------------------ start
  async function start() {
    window.polmapConsole = { ready: false };
    $('panel-toggle').addEventListener('click', () => {
      const p = $('panel');
      p.classList.toggle('hidden');
      $('panel-toggle').setAttribute('aria-expanded', String(!p.classList.contains('hidden')));
      if (state.map) state.map.resize();
    });
    const list = await getJson('/v1/maps');
    state.versions = list.versions;
    state.current = list.current;
    if (list.current === null) {
      $('version-label').textContent = 'no map version published yet';
      window.polmapConsole.ready = true;
      return;
    }
    const cur = state.versions.find((v) => v.version === list.current) || {};
    const g = (cur.statistics && cur.statistics.gridmap) || {};
    state.tilejson = await getJson('/v1/tilejson.json');
    $('version-label').textContent = 'map version ' + list.current;
    const map = initMap(state.tilejson, Number.isInteger(g.base_zoom) ? g.base_zoom : 20);
    fillVersions();
    $('layer-points').addEventListener('change', (e) => setVisible(['points'], e.target.checked));
    $('layer-lines').addEventListener('change', (e) => setVisible(['lines'], e.target.checked));
    $('layer-gridmap').addEventListener('change', gridmapLayers);
    for (const r of document.querySelectorAll('input[name="gridmap-style"]')) r.addEventListener('change', gridmapLayers);
    $('layer-coverage').addEventListener('change', (e) => setVisible(['coverage'], e.target.checked));
    $('layer-diff').addEventListener('change', (e) => setVisible(['diff-points', 'diff-lines'], e.target.checked));
    $('layer-run').addEventListener('change', (e) => setVisible(['run'], e.target.checked));
    $('layer-quality').addEventListener('change', (e) => setVisible(['quality'], e.target.checked));
    $('quality-all-runs').addEventListener('change', () => loadQuality().catch((e) => { $('runs-status').textContent = String(e.message || e); }));
    for (const r of document.querySelectorAll('input[name="run-colour"]')) r.addEventListener('change', runColouring);
    $('layer-hdmap').addEventListener('change', (e) => setVisible(HDMAP_LAYERS, e.target.checked));
    $('hdmap-name').addEventListener('change', (e) => showHdmap(e.target.value).catch((err) => { $('hdmap-summary').textContent = String(err.message || err); }));
    $('diff-show').addEventListener('click', () => showDiff().catch((e) => { $('diff-summary').textContent = String(e.message || e); }));
    $('build-start').addEventListener('click', startBuild);
    $('key-form').addEventListener('submit', (e) => {
      e.preventDefault();
      const input = $('api-key');
      state.key = input.value.trim() || null;
      input.value = '';  // out of the DOM as soon as it is read
      loadFleet();
      loadRuns();
    });
    loadFleet();
    loadRuns();
    // The overlay's source exists once the style has loaded.
    const hdmapLoaded = new Promise((resolve) => map.once('load', () => loadHdmap().finally(resolve)));
    map.once('idle', async () => { await hdmapLoaded; window.polmapConsole.ready = true; });
  }

  document.addEventListener('DOMContentLoaded', () => {
    start().catch((e) => {
      $('version-label').textContent = String(e.message || e);
      window.polmapConsole = { ready: true, error: String(e.message || e) };
    });
  });
})();
