function out = magnet_request(method, url, token, timeout, varargin)
%MAGNET_REQUEST One call to the MAGNET HTTP API; returns the decoded JSON answer.
%   out = magnet_request('get', url, token, timeout)
%   out = magnet_request('post', url, token, timeout, 'name1', 'value1', ...)  (form-urlencoded)
%   The server is asked to put errors in the body (?errors=body) because Octave's webread/webwrite
%   drop the body of 4xx/5xx answers; an answer with a `detail` field is raised as an error.

  url = magnet_errors_in_body(url);
  % Octave 7 sends at most one header (it flattens HeaderFields): the API key
  opts = weboptions('Timeout', timeout, 'ContentType', 'text', 'RequestMethod', method);
  if ~isempty(token)
    opts.HeaderFields = {'Authorization', ['Bearer ' token]};
  end
  if strcmpi(method, 'post')
    text = webwrite(url, varargin{:}, opts);
  else
    text = webread(url, opts);
  end
  if ~ischar(text)
    text = char(text(:)');
  end
  out = jsondecode(text);
  if isstruct(out) && isfield(out, 'detail')
    status = 0;
    if isfield(out, 'status')
      status = out.status;
    end
    detail = out.detail;
    if ~ischar(detail)
      detail = jsonencode(detail);
    end
    error('magnet:http', 'MAGNET server (HTTP %d): %s', status, detail);
  end
end

function url = magnet_errors_in_body(url)
  if any(url == '?')
    url = [url '&errors=body'];
  else
    url = [url '?errors=body'];
  end
end
