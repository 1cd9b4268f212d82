function out = magnet_request(method, url, token, timeout, varargin)
%MAGNET_REQUEST One call to the MAGNET HTTP API; returns the decoded JSON answer.
%   out = magnet_request('get', url, token, timeout)
%   out = magnet_request('post', url, token, timeout, 'name1', 'value1', ...)  (form-urlencoded)
%   The server is asked to put errors in the body (?errors=body) because Octave's webread/webwrite
%   drop the body of 4xx/5xx answers; an answer with a `detail` field is raised as an error
%   (identifier magnet:http). A 429 (too many queued jobs) or 503 (job queue down) is retried up to
%   5 times, as the Python client does: such a submission was not queued, so sending it again is
%   safe. The wait is the answer's retry_after when it has one (Octave's webread cannot see the
%   Retry-After header), else 1, 2, 4, 8, 16 s. A server that cannot be reached is the error
%   magnet:connect, naming its address.

  retries = 5;
  url = magnet_errors_in_body(url);
  % Octave 7 sends at most one header (it flattens HeaderFields): the API key
  opts = weboptions('Timeout', timeout, 'ContentType', 'text', 'RequestMethod', method);
  if ~isempty(token)
    opts.HeaderFields = {'Authorization', ['Bearer ' token]};
  end
  for attempt = 0:retries
    try
      if strcmpi(method, 'post')
        text = webwrite(url, varargin{:}, opts);
      else
        text = webread(url, opts);
      end
    catch err
      magnet_connect_error(url, err);
    end
    if ~ischar(text)
      text = char(text(:)');
    end
    out = jsondecode(text);
    if ~(isstruct(out) && isfield(out, 'detail'))
      return
    end
    status = 0;
    if isfield(out, 'status')
      status = out.status;
    end
    if any(status == [429 503]) && attempt < retries
      wait = 2 ^ attempt;
      if isfield(out, 'retry_after') && isnumeric(out.retry_after)
        wait = out.retry_after;
      end
      pause(min(wait, 30));
      continue
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
