function magnet_download(url, file, token, timeout)
%MAGNET_DOWNLOAD Save the body of GET url to file (binary-safe in MATLAB and Octave).
  if any(url == '?')
    url = [url '&errors=body'];
  else
    url = [url '?errors=body'];
  end
  headers = {};
  if ~isempty(token)
    headers = {'Authorization', ['Bearer ' token]};  % Octave 7 sends one header at most
  end
  if exist('OCTAVE_VERSION', 'builtin')
    % Octave has no websave; webread with ContentType 'text' hands back the raw bytes as char
    opts = weboptions('HeaderFields', headers, 'Timeout', timeout, 'ContentType', 'text');
    try
      data = webread(url, opts);
    catch err
      magnet_connect_error(url, err);
    end
    if numel(data) > 0 && data(1) == '{'
      magnet_raise(data);
    end
    fid = fopen(file, 'w');
    fwrite(fid, uint8(data), 'uint8');
    fclose(fid);
  else
    opts = weboptions('HeaderFields', headers, 'Timeout', timeout);
    try
      websave(file, url, opts);
    catch err
      magnet_connect_error(url, err);
    end
    fid = fopen(file, 'r');
    first = fread(fid, 1, '*char');
    fclose(fid);
    if ~isempty(first) && first == '{'
      magnet_raise(fileread(file));
    end
  end
end

function magnet_raise(text)
  out = jsondecode(text);
  error('magnet:http', 'MAGNET server (HTTP %d): %s', out.status, out.detail);
end
