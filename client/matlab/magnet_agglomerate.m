function [region, neighbor, job, levels] = magnet_agglomerate(mesh_file, varargin)
%MAGNET_AGGLOMERATE Agglomerate a mesh on a MAGNET server; return the lymph region/neighbor structs.
%
%   [region, neighbor] = magnet_agglomerate('mesh.vtu', 'K', 64)
%   [region, neighbor, job] = magnet_agglomerate('mesh.vtu', 'Server', 'http://gpu-box:8000', ...
%       'Token', 'my-api-key', 'Model', 'metis', 'Mode', 'kway', 'K', 128, 'SaveAs', 'brain128.mat')
%   [region, neighbor, job, levels] = magnet_agglomerate('mesh.vtu', 'Model', 'sage-base', ...
%       'Mode', 'multilevel', 'Nref', 7, 'Refiner', 'fm', 'Hierarchy', true)
%
%   Uploads the mesh, submits a job, polls it and downloads the lymph structs of the agglomerated
%   (2D) mesh, ready for a PolyDG solve: region (coord, connectivity, ne, nedges, coords_element,
%   id, tag, connectivity_bc, bc_tag, BBox, area, max_kb) and neighbor (nedges, neigh,
%   neighedges), all 1-based. Runs in MATLAB and in GNU Octave 7 (webwrite/webread/weboptions).
%
%   Name-value options (all optional):
%     Server      server URL (default: env MAGNET_SERVER, else http://127.0.0.1:8000)
%     Token       API key (default: env MAGNET_TOKEN; none for a keyless local server)
%     Model       'metis' (default) | 'kmeans' | 'rtree' | 'sage-base' | 'sage-hetero' | 'rl-partitioner'
%     Mode        'kway' (default) | 'nref' | 'target-size' | 'mult-factor' | 'segregated' | 'coarsen'
%                 | 'multilevel'
%     Refiner     'fm' | 'rl-refiner': refine every bisection (k-way mode: 'fm')
%     Threshold   multilevel: coarsen every subgraph to at most this many cells (default 200)
%     Hierarchy   true: also return every nested level in `levels` (recursive modes)
%     Ratio       with Hierarchy: nested levels of their own (any mode, any model: rtree, metis, ...),
%                 Ratio times fewer elements per level (as `magnet hierarchy`); Coarsest: at most
%                 this many elements on the coarsest level (default 10)
%     K, Nref, TargetSize, MultFactor   the size parameter of the mode
%     Subset      cell ids (0-based, as in the mesh file) to agglomerate, mode 'coarsen'
%     Seed, PhysicalTag, Absorb, Method, HolePolicy, BoundaryTag   as in `magnet agglomerate`
%                 (BoundaryTag: bc_tag of boundary edges that have no boundary group, default 1)
%     Fill        true: the mesh is a closed surface (.stl, .obj, .ply, .off), filled with tetrahedra
%                 first (options.fill); that makes a 3D mesh, so give Output (see below)
%     AllowExtra  true: keep every connected fragment as an element (more than K where a part is
%                 disconnected); Weld: merge points closer than this distance first
%     Output      also save the agglomerated mesh (.vtu) here. A 3D mesh has no lymph structs (they
%                 are 2D only): with Output its job runs and region, neighbor are empty; without it
%                 the wrapper refuses it before the job runs (error magnet:dim)
%     SaveAs      also save region and neighbor to this .mat file
%     Timeout     seconds to wait for the job (default 3600)
%     Poll        seconds between status checks (default 1)
%     Verbose     print progress (default true)
%
%   region.bc_tag holds the boundary group (gmsh physical curve) of each boundary edge, in the
%   order of region.connectivity_bc; region.id the element's physical group. The job output
%   carries the mesh summary: job.mesh.boundary.groups lists each group's tag and name.
%
%   levels (with 'Hierarchy', true): a cell array, coarsest level first, the last one the result;
%   levels{L}.region / levels{L}.neighbor are that level's lymph structs and levels{L}.parent
%   (L >= 2) gives, for each element of level L, its element (1-based) in level L-1: every coarse
%   element is exactly the union of the finer elements that name it. levels{L}.P is the aggregation
%   operator into level L (sparse, a single 1 per row; rows: the elements of level L+1, or the fine
%   cells for the last level), what an algebraic multigrid takes as its aggregates.
%
%   Errors of the server (bad mesh, bad parameter, failed job) are raised as MATLAB/Octave errors
%   with the server's message (identifier magnet:http, magnet:job); a full queue (429) or a job
%   queue that is down (503) is retried a few times first; a server that cannot be reached is
%   magnet:connect, a mesh file that cannot be read magnet:file.

  p = struct('Server', getenv('MAGNET_SERVER'), 'Token', getenv('MAGNET_TOKEN'), 'Model', 'metis', ...
             'Mode', 'kway', 'K', [], 'Nref', [], 'TargetSize', [], 'MultFactor', [], 'Subset', [], ...
             'Seed', [], 'PhysicalTag', '', 'Absorb', [], 'Method', '', 'HolePolicy', '', 'BoundaryTag', [], ...
             'Refiner', '', 'Threshold', [], 'Hierarchy', false, 'Ratio', [], 'Coarsest', [], ...
             'Fill', false, 'AllowExtra', false, 'Weld', [], 'Output', '', ...
             'SaveAs', '', 'Timeout', 3600, 'Poll', 1, 'Verbose', true);
  if mod(numel(varargin), 2) ~= 0
    error('magnet:args', 'options must be name-value pairs');
  end
  names = fieldnames(p);
  for i = 1:2:numel(varargin)
    hit = find(strcmpi(names, varargin{i}));
    if isempty(hit)
      error('magnet:args', 'unknown option ''%s''', varargin{i});
    end
    p.(names{hit}) = varargin{i + 1};
  end
  if isempty(p.Server)
    p.Server = 'http://127.0.0.1:8000';
  end
  server = regexprep(p.Server, '/+$', '');

  % what can be known here is refused before the server is asked
  if ~ischar(mesh_file) || isempty(mesh_file)
    error('magnet:file', 'the mesh file must be given as a file name');
  end
  if exist(mesh_file, 'dir')
    error('magnet:file', 'cannot read %s: it is a folder, not a file (send a case folder as a .zip)', mesh_file);
  end
  if ~exist(mesh_file, 'file')
    error('magnet:file', 'cannot read %s: no such file', mesh_file);
  end
  for out = {p.Output, p.SaveAs}
    target = out{1};
    if ~isempty(target)
      folder = fileparts(target);
      if exist(target, 'dir')
        error('magnet:file', 'cannot write %s: it is a folder; give a file name', target);
      end
      if ~isempty(folder) && ~exist(folder, 'dir')
        error('magnet:file', 'cannot write %s: folder %s does not exist', target, folder);
      end
    end
  end
  if p.Fill && isempty(p.Output)
    error('magnet:dim', ['lymph''s region/neighbor structs are for 2D meshes only and Fill makes a 3D ' ...
          'mesh: give ''Output'', ''file.vtu'' to get the agglomerated mesh']);
  end
  if p.Fill && p.Hierarchy
    error('magnet:dim', 'the levels of a hierarchy come as lymph structs, 2D only: Fill makes a 3D mesh');
  end

  % upload + submit in one form-urlencoded request (all Octave's webwrite can send)
  fid = fopen(mesh_file, 'r');
  if fid < 0
    error('magnet:file', 'cannot read %s: permission denied', mesh_file);
  end
  bytes = fread(fid, Inf, '*uint8');
  fclose(fid);
  [~, base, ext] = fileparts(mesh_file);
  fields = {'file_b64', matlab.net.base64encode(bytes(:)'), 'filename', [base ext], ...
            'model', p.Model, 'mode', p.Mode};
  fields = add_field(fields, 'k', p.K);
  fields = add_field(fields, 'nref', p.Nref);
  fields = add_field(fields, 'target_size', p.TargetSize);
  fields = add_field(fields, 'mult_factor', p.MultFactor);
  fields = add_field(fields, 'seed', p.Seed);
  fields = add_field(fields, 'physical_tag', p.PhysicalTag);
  fields = add_field(fields, 'absorb_fraction', p.Absorb);
  fields = add_field(fields, 'method', p.Method);
  fields = add_field(fields, 'hole_policy', p.HolePolicy);
  fields = add_field(fields, 'boundary_tag', p.BoundaryTag);
  fields = add_field(fields, 'refiner', p.Refiner);
  fields = add_field(fields, 'threshold', p.Threshold);
  if p.Hierarchy
    fields = [fields, {'hierarchy', 'true'}];
  end
  if p.Fill
    fields = [fields, {'fill', 'true'}];
  end
  if p.AllowExtra
    fields = [fields, {'allow_extra', 'true'}];
  end
  fields = add_field(fields, 'weld', p.Weld);
  fields = add_field(fields, 'ratio', p.Ratio);
  fields = add_field(fields, 'coarsest', p.Coarsest);
  if ~isempty(p.Subset)
    fields = [fields, {'subset', sprintf('%d,', p.Subset(:))}];
  end
  try
    job = magnet_request('post', [server '/v1/agglomerate/form'], p.Token, 120, fields{:});
  catch err
    % the server's advice names job options: said as this function's options
    msg = strrep(err.message, 'set options.fill = true', ...
                 'give ''Fill'', true (with ''Output'', ''file.vtu'')');
    msg = strrep(msg, 'options.allow_extra', '''AllowExtra'', true');
    msg = strrep(msg, 'options.weld', '''Weld''');
    error(err.identifier, '%s', msg);
  end
  if p.Verbose
    fprintf('magnet: job %s %s\n', job.id, job.status);
  end

  % the uploaded mesh's summary (cells, dimension, physical and boundary groups with their names)
  mesh = magnet_request('get', [server '/v1/meshes/' job.mesh_id], p.Token, 60);
  three_d = p.Fill || (isfield(mesh, 'dim') && mesh.dim ~= 2);
  if three_d && (isempty(p.Output) || p.Hierarchy)
    % no lymph structs for it: take the job back before it runs (or while it starts)
    try
      magnet_request('delete', [server '/v1/jobs/' job.id '?purge=true'], p.Token, 60);
    catch
    end
    [~, base, ext] = fileparts(mesh_file);
    if p.Hierarchy
      error('magnet:dim', ['the levels of a hierarchy come as lymph structs, 2D only, and %s is 3D ' ...
            '(its job was cancelled)'], [base ext]);
    end
    error('magnet:dim', ['lymph''s region/neighbor structs are for 2D meshes only and %s is 3D ' ...
          '(its job was cancelled): give ''Output'', ''file.vtu'' to get the agglomerated mesh'], [base ext]);
  end

  % poll until the job ends
  t0 = tic;
  last = '';
  while ~any(strcmp(job.status, {'succeeded', 'failed', 'cancelled'}))
    if toc(t0) > p.Timeout
      error('magnet:timeout', 'job %s still %s after %g s', job.id, job.status, p.Timeout);
    end
    pause(p.Poll);
    job = magnet_request('get', [server '/v1/jobs/' job.id], p.Token, 60);
    stage = job.status;
    if isfield(job, 'stage') && ischar(job.stage)
      stage = job.stage;
    end
    line = sprintf('magnet: %-10s %3.0f%%', stage, 100 * job.progress);
    if p.Verbose && ~strcmp(line, last)
      fprintf('%s\n', line);
      last = line;
    end
  end
  if ~strcmp(job.status, 'succeeded')
    msg = '';
    if isfield(job, 'error') && ischar(job.error)
      msg = job.error;
    end
    error('magnet:job', 'job %s %s: %s', job.id, job.status, msg);
  end

  job.mesh = mesh;
  if ~isempty(p.Output)
    magnet_download([server '/v1/jobs/' job.id '/mesh'], p.Output, p.Token, 600);
  end
  if three_d
    region = [];
    neighbor = [];
    levels = {};
    if p.Verbose
      fprintf('magnet: %d elements (3D: no lymph structs) -> %s\n', job.result.elements, p.Output);
    end
    return
  end

  % the lymph structs, as the .mat file the server wrote
  matfile = [tempname() '.mat'];
  magnet_download([server '/v1/jobs/' job.id '/lymph?format=mat'], matfile, p.Token, 120);
  s = load(matfile);
  region = s.region;
  neighbor = s.neighbor;
  if ~isempty(p.SaveAs)
    copyfile(matfile, p.SaveAs);
  end
  delete(matfile);
  if p.Verbose
    fprintf('magnet: %d elements\n', region.ne);
  end

  % every nested level: the zip of lymph .mat files and parent maps
  levels = {};
  if p.Hierarchy
    hdir = tempname();
    mkdir(hdir);
    zipfile = fullfile(hdir, 'hierarchy.zip');
    magnet_download([server '/v1/jobs/' job.id '/hierarchy'], zipfile, p.Token, 600);
    unzip(zipfile, hdir);
    index = jsondecode(fileread(fullfile(hdir, 'hierarchy.json')));
    entries = index.levels;
    if ~iscell(entries)
      entries = num2cell(entries);
    end
    levels = cell(1, numel(entries));
    for L = 1:numel(entries)
      e = entries{L};
      s = load(fullfile(hdir, e.lymph_mat));
      lev = struct('region', s.region, 'neighbor', s.neighbor, 'parent', [], 'P', []);
      if isfield(e, 'parent') && ischar(e.parent)
        parent = jsondecode(fileread(fullfile(hdir, e.parent)));
        lev.parent = parent(:) + 1;
      end
      levels{L} = lev;
    end
    % aggregation operators: into level L from level L+1 (parent maps), into the last from the cells
    for L = 1:numel(levels) - 1
      par = levels{L + 1}.parent;
      levels{L}.P = sparse(1:numel(par), par, 1, numel(par), levels{L}.region.ne);
    end
    cells = jsondecode(fileread(fullfile(hdir, entries{end}.labels)));
    levels{end}.P = sparse(1:numel(cells), cells(:) + 1, 1, numel(cells), levels{end}.region.ne);
    if exist('OCTAVE_VERSION', 'builtin')
      confirm_recursive_rmdir(false, 'local');
    end
    rmdir(hdir, 's');
    if p.Verbose
      fprintf('magnet: %d nested levels\n', numel(levels));
    end
  end
end

function fields = add_field(fields, name, value)
  if isempty(value)
    return
  end
  if isnumeric(value)
    value = sprintf('%.17g', value);
  end
  fields = [fields, {name, value}];
end
